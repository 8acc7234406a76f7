"""A newcomer's first run, timed: clone the repository, run the README's Quick start commands (issue 27,
item 4; targets: the main job under 60 s after the install step, the tests under 5 min, on 2 cores).

The Quick start's first command is `<install> && deint run ...`: this script splits it at the `deint`
command and times the two parts apart, then times the second command (the test suite).  The clone is
fresh, so nothing is cached: numba compiles every kernel the main job calls (its cache lives beside
the sources, in the clone).  `../shared` beside this repository (the papers) is linked beside the clone,
as CI has it.  Each figure is wall time, with the CPU time of the command's processes beside it: on a
busy machine the wall time is that CPU time stretched by the other load, so run it on an idle one.
Prints figures; asserts nothing.

    python benchmarks/bench_first_run.py [--skip-tests] [--keep DIR]
"""

from __future__ import annotations

import argparse
import re
import resource
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {"main job": 60.0, "tests": 300.0}  # seconds of wall time, after the install step


def quick_start(readme: Path) -> list[str]:
    """The command lines of README.md's first code block under '## Quick start' (as .ci/run reads it)."""
    text = readme.read_text()
    block = re.search(r"^## Quick start\n.*?^```[a-z]*\n(.*?)^```", text, re.S | re.M)
    if block is None:
        raise SystemExit("README.md has no code block under '## Quick start'")
    return [line for line in block.group(1).splitlines() if line.strip()]


def split_main_job(first: str) -> tuple[str, str]:
    """(the install step, the main job) of the first command: it is cut before its `deint` command."""
    parts = first.split(" && ")
    at = next((i for i, p in enumerate(parts) if p.startswith("deint ")), None)
    if at is None or at == 0:
        raise SystemExit(f"the Quick start's first command has no `... && deint ...` main job: {first!r}")
    venv = ". .venv/bin/activate"
    return " && ".join(parts[:at]), " && ".join([venv, *parts[at:]])


def timed(cmd: str, cwd: Path) -> tuple[float, float, int]:
    """(wall s, CPU s of its processes, exit status) of one bash command, its output passed through."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    status = subprocess.run(["bash", "-euo", "pipefail", "-c", cmd], cwd=cwd).returncode
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), status


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--skip-tests", action="store_true", help="time the install step and the main job only")
    ap.add_argument("--keep", type=Path, default=None, help="clone into this new folder and keep it")
    args = ap.parse_args()

    work = args.keep or Path(tempfile.mkdtemp(prefix="deint-first-run-"))
    work.mkdir(parents=True, exist_ok=True)
    clone = work / "main"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    if (ROOT.parent / "shared").exists() and not (work / "shared").exists():
        (work / "shared").symlink_to(ROOT.parent / "shared")
    commands = quick_start(clone / "README.md")
    install, main_job = split_main_job(commands[0])
    steps = [("install", install), ("main job", main_job)]
    if not args.skip_tests:
        steps += [("tests", command) for command in commands[1:]]

    rows = []
    try:
        for name, cmd in steps:
            print(f"+ {cmd}", flush=True)
            wall, cpu, status = timed(cmd, clone)
            rows.append((name, wall, cpu, status))
            if status:
                break
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)

    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    print(f"\nfresh clone of {ROOT} at {head.stdout.strip()}")
    print(f"{'step':<10} {'wall s':>8} {'CPU s':>8} {'target s':>9}  status")
    for name, wall, cpu, status in rows:
        target = TARGETS.get(name)
        verdict = "" if target is None else ("  meets" if wall <= target else "  misses")
        print(f"{name:<10} {wall:>8.1f} {cpu:>8.1f} {target if target else '-':>9}  exit {status}{verdict}")


if __name__ == "__main__":
    main()

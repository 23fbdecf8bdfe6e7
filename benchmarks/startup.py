"""Wall time of a first ``planbench plan`` (issue 19, item 9): numba's cache cold (an empty
``NUMBA_CACHE_DIR``, as on a fresh install), then warm, and cold with ``--set backend=numba`` (the
compilation in the foreground, as before planbench.runtime.compile_cache). Medians of ``--repeat`` runs.

    python benchmarks/startup.py [--problem mbm:box/0001] [--planner matrix-field] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PLANBENCH = Path(sys.executable).with_name("planbench")


def _wait_for_background(cache: str) -> None:
    """Until the background compilation started by a cold run has left its marker (or 120 s)."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if any(p.name.startswith("numba-warm-") and p.suffix != ".lock" for p in Path(cache, "planbench").glob("*")):
            return
        time.sleep(0.5)


def _plan(cache: str, args: argparse.Namespace, *extra: str) -> float:
    env = {**os.environ, "NUMBA_CACHE_DIR": cache, "PLANBENCH_BACKGROUND_COMPILE": "1"}
    cmd = [str(PLANBENCH), "plan", "--problem", args.problem, "--planner", args.planner, *extra]
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--problem", default="mbm:box/0001")
    parser.add_argument("--planner", default="matrix-field")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    times: dict[str, list[float]] = {"cold": [], "warm": [], "cold, backend=numba": []}
    for _ in range(args.repeat):
        cache = tempfile.mkdtemp(prefix="planbench-startup-")
        try:
            times["cold"].append(_plan(cache, args))
            _wait_for_background(cache)  # so that it does not share the cores with the next runs
            times["warm"].append(_plan(cache, args))
        finally:
            shutil.rmtree(cache, ignore_errors=True)
        cache = tempfile.mkdtemp(prefix="planbench-startup-")
        try:
            times["cold, backend=numba"].append(_plan(cache, args, "--set", "backend=numba"))
        finally:
            shutil.rmtree(cache, ignore_errors=True)
    print(f"planbench plan --problem {args.problem} --planner {args.planner}, median of {args.repeat} [s]")
    for name, values in times.items():
        print(f"  {name:22s} {statistics.median(values):6.2f}   ({', '.join(f'{v:.2f}' for v in values)})")


if __name__ == "__main__":
    main()

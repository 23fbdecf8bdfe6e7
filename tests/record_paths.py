"""Record the field planners' paths on a fixed set of problems (tests/data/recorded_paths.npz).

Run once before a refactoring that must not change behaviour; ``test_same_paths.py`` then replans
the same problems with the same seeds and compares. Usage: ``python tests/record_paths.py``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

import planbench

HERE = Path(__file__).parent
DATA = HERE / "data"
CASES = HERE / "data" / "recorded_cases.json"
OUT = DATA / "recorded_paths.npz"


def main() -> None:
    cases = json.loads(CASES.read_text())
    arrays = {}
    for case in cases:
        problem = load_case(case)
        result = plan_case(case, problem)
        key = case_key(case)
        arrays[key] = np.asarray(result.path, dtype=float)
        print(f"{key}: {result.status.value} {len(result.path)} waypoints", file=sys.stderr)
    np.savez_compressed(OUT, **arrays)


def case_key(case: dict) -> str:
    settings = ",".join(f"{k}={v}" for k, v in sorted(case.get("settings", {}).items()))
    return f"{case['planner']}|{case['problem']}|{settings}"


def plan_case(case: dict, problem: planbench.Problem) -> planbench.PlanResult:
    return planbench.plan(
        problem, planner=case["planner"], seed=case["seed"], time_limit=60.0, **case.get("settings", {})
    )


def load_case(case: dict) -> planbench.Problem:
    ref = case["problem"]
    if ref.startswith("mbm:"):
        return planbench.load_problems(ref)[0]
    return planbench.load_problems(str(DATA / ref))[0]


if __name__ == "__main__":
    main()

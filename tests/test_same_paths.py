"""The field planners give the same paths as recorded before a refactoring (tests/record_paths.py).

The recorded set covers four MotionBenchMaker families, a generated UR5 and Panda scene, every
field planner, both step backends, the lazy field and the tool repulsion. Paths are compared
waypoint by waypoint to 1e-4 rad. A refactoring that only reorders floating-point operations moves
most paths by 1e-11 rad or less; where a planner's step is sensitive, rounding grows along the
path: reading the obstacles' quaternions with pinocchio instead of scipy (a 1e-16 change of the
rotation matrices) moved distance-field's path on the generated Panda scene by 1.6e-5 rad after
500 steps (coal's witness points). Turning off coal's cached GJK guess (distances no longer
depend on the queries before) moved that path by 2.1e-4 rad; it was recorded again, and again
when coal's box support was made exact whatever a process queries first (it moved 1.0e-4 rad when
another test file ran first: planbench/geometry/box_support.py). A real change of behaviour moves
paths by far more, or changes their length.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from record_paths import CASES, OUT, case_key, load_case, plan_case

RECORDED = np.load(OUT)
ALL_CASES = json.loads(CASES.read_text())


@pytest.mark.parametrize("case", ALL_CASES, ids=case_key)
def test_same_path_as_recorded(case: dict) -> None:
    path = np.asarray(plan_case(case, load_case(case)).path, dtype=float)
    recorded = RECORDED[case_key(case)]
    assert path.shape == recorded.shape, f"{len(path)} waypoints, recorded {len(recorded)}"
    np.testing.assert_allclose(path, recorded, rtol=0, atol=1e-4)

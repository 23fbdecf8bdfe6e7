"""Cost of one repulsion query of the calibrated field beside the matrix field and edt-field (issue 32).

    python benchmarks/calibrated_step.py

For each problem, the Panda at 8 configurations along a ``matrix-field`` path; per variant the
median over configurations of the median time of ``repulsion.forces(kin)`` (after
``kin.update(q)``, untimed) [us], and its ratio to ``matrix-field`` (full mode) measured in the
same run. ``full``: the field precomputed in setup and sampled; ``lazy``: evaluated from the grid
at the control points every query (the controllers' default). One process, numba's threads as set.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

import numpy as np

import planbench
from planbench_plugins.ik_loop import ArmKinematics
from planbench_plugins.matrix_field import MatrixFieldPlanner
from planbench_plugins.potential_fields import EDTFieldPlanner

PROBLEMS = ("mbm:box/0001", "mbm:bookshelf_small/0001", "mbm:cage/0001", "mbm:table_pick/0001")
VARIANTS: dict[str, tuple[Any, dict[str, Any]]] = {
    "matrix-field full": (MatrixFieldPlanner, {}),
    "matrix-field lazy": (MatrixFieldPlanner, {"field_mode": "lazy"}),
    "calibrated full": (MatrixFieldPlanner, {"field_kind": "calibrated"}),
    "calibrated lazy": (MatrixFieldPlanner, {"field_kind": "calibrated", "field_mode": "lazy"}),
    "edt-field": (EDTFieldPlanner, {}),
}


def _median_us(fn: Any, reps: int = 100, batches: int = 5) -> float:
    out = []
    for _ in range(batches):
        t0 = time.perf_counter()
        for _ in range(reps):
            fn()
        out.append((time.perf_counter() - t0) / reps * 1e6)
    return statistics.median(out)


def main() -> None:
    times: dict[str, list[float]] = {name: [] for name in VARIANTS}
    setups: dict[str, list[float]] = {name: [] for name in VARIANTS}
    for pid in PROBLEMS:
        problem = planbench.load_problems(pid)[0]
        ref = planbench.plan(problem, MatrixFieldPlanner, time_limit=5.0)
        assert ref.path is not None, ref.message
        configs = ref.path[np.linspace(0, len(ref.path) - 1, 8).astype(int)]
        for name, (cls, settings) in VARIANTS.items():
            planner = cls(**settings)
            t0 = time.perf_counter()
            planner.setup(problem)
            setups[name].append((time.perf_counter() - t0) * 1e3)
            rep = planner.stepper.repulsion
            kin = ArmKinematics(
                problem.robot,
                problem.robot.frame_id(problem.goal.pose.frame),
                planner.stepper.control_points,
                compiled=planner.use_numba,
            )
            for q in configs:
                kin.update(q)
                times[name].append(_median_us(lambda rep=rep, kin=kin: rep.forces(kin)))
        print(f"done {pid}", flush=True)
    base = statistics.median(times["matrix-field full"])
    print("\n| variant | repulsion query [us] | vs matrix-field full | setup [ms] |")
    print("| --- | --- | --- | --- |")
    for name in VARIANTS:
        t = statistics.median(times[name])
        print(f"| {name} | {t:.1f} | {t / base:.2f}x | {statistics.median(setups[name]):.0f} |")


if __name__ == "__main__":
    main()

"""How much of the unknown space next to the arm at the start the arm itself hides.

    python benchmarks/arm_shadow.py                               # the four scenarios of docs/reactive.md
    python benchmarks/arm_shadow.py dynamic-tune:ur5_crossing_fast_depth/0004 --near 3 --far 6

For each depth scenario, the first frame (memory ``"frame"``: one frame, no map) is captured twice
with the same noise: once with the arm at its start, once with it at its goal. Of the cells
``near``-``far`` cells from the arm's body at the start (and more than ``far`` from it at the goal)
that the first frame leaves unknown, printed: how many, and how many of them the frame with the
arm at its goal sees. Those are hidden by the arm itself, not by an obstacle: what stops
``ompl-replan``'s first path short in its safe mode (docs/reactive.md, "The arm's own shadow at
the start").
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
from scipy import ndimage

from planbench.reactive.body import ArmBody
from planbench.reactive.sensing import Sensor
from planbench.reactive.sets import load_scenario

DEFAULT = (
    "dynamic-test:panda_pair_fast_depth/0003",
    "dynamic-test:panda_crossing_slow_depth/0003",
    "dynamic-test:xarm7_pair_fast_depth/0008",
    "dynamic-test:ur5_crossing_slow_depth/0005",
)


def shadow(name: str, near: float, far: float) -> tuple[int, int]:
    """(unknown cells in the shell around the arm at the start, of them seen with the arm at its goal)."""
    scenario = load_scenario(name)
    problem = scenario.problem
    if scenario.sensing.model != "depth" or problem.goal.q is None:
        raise SystemExit(f"{name}: needs depth sensing and a goal configuration")
    settings = dataclasses.replace(scenario.sensing, memory="frame")
    scene = scenario.scene_at(0.0)
    start, goal = np.asarray(problem.start, dtype=float), np.asarray(problem.goal.q, dtype=float)
    at_start = Sensor(settings, problem.robot).capture(scene, start, 0.0, 0, np.random.default_rng(0))
    at_goal = Sensor(settings, problem.robot).capture(scene, goal, 0.0, 0, np.random.default_rng(0))
    grid = at_start.grid
    assert grid.known is not None and at_goal.grid.known is not None
    body = ArmBody(problem.robot, grid.origin, grid.shape, grid.resolution)
    from_start = ndimage.distance_transform_edt(~body.mark(np.zeros(grid.shape, dtype=bool), start))
    from_goal = ndimage.distance_transform_edt(~body.mark(np.zeros(grid.shape, dtype=bool), goal))
    shell = (from_start > near) & (from_start <= far) & (from_goal > far)
    unknown = shell & ~grid.known
    return int(unknown.sum()), int((unknown & at_goal.grid.known).sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenarios", nargs="*", default=list(DEFAULT))
    parser.add_argument("--near", type=float, default=2.0, help="inner radius [cells], exclusive (default 2)")
    parser.add_argument("--far", type=float, default=6.0, help="outer radius [cells] (default 6)")
    args = parser.parse_args()
    shell = f"{args.near:g}-{args.far:g} cells"
    print(f"| scenario | unknown {shell} from the arm at the start | seen with the arm at its goal |")
    print("|---|---|---|")
    for name in args.scenarios:
        unknown, seen = shadow(name, args.near, args.far)
        share = f" ({100 * seen / unknown:.0f} %)" if unknown else ""
        print(f"| `{name}` | {unknown} | {seen}{share} |", flush=True)


if __name__ == "__main__":
    main()

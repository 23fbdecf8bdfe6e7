"""What a sensor frame costs ``ompl-replan``: CPU time of the tick that takes in a new frame.

    python benchmarks/ompl_replan_frames.py                       # six fast depth scenarios of dynamic-tune
    python benchmarks/ompl_replan_frames.py dynamic-tune:panda_crossing_fast_depth/0001

Each scenario is run in this process with ideal timing (no compute charged, so every run sees the
same frames at the same times whatever the machine's load); a frame's tick is its ``update`` plus
the ``step`` after it, timed with the process's CPU clock. Ticks that (re)plan are left out: a
plan is charged as such, and its cost is the planner's time limit. Printed per scenario and over
all: the median and 90th percentile [ms] and the share of frame ticks over the 10 ms control
period (each of them a missed deadline in a measured run).
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np

from planbench.reactive.controller import Controller
from planbench.reactive.runner import RunSettings, run_scenario
from planbench.reactive.sets import load_scenario
from planbench.registry import make_controller

DEFAULT = (
    "dynamic-tune:panda_crossing_fast_depth/0001",
    "dynamic-tune:panda_reaching_fast_depth/0001",
    "dynamic-tune:panda_occluded_fast_depth/0001",
    "dynamic-tune:ur5_swinging_fast_depth/0004",
    "dynamic-tune:xarm7_sliding_fast_depth/0007",
    "dynamic-tune:xarm7_pair_fast_depth/0007",
)
PERIOD_MS = 10.0


class FrameTimer(Controller):
    """Passes every call on to ``inner`` and times the tick that follows each frame."""

    name = "ompl-replan"

    def __init__(self, inner: Controller) -> None:
        self.inner = inner
        self.ticks: list[float] = []  # [s] CPU time of each frame's tick that did not plan
        self.pending: float | None = None  # [s] the last frame's update, until the step after it

    def setup(self, task: Any) -> None:
        self.inner.setup(task)

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        self.inner.reset(q, rng)

    def update(self, observation: Any) -> None:
        t0 = time.process_time()
        self.inner.update(observation)
        self.pending = time.process_time() - t0

    def step(self, t: float, q: np.ndarray, observation: Any, goal: Any) -> np.ndarray:
        pending, self.pending = self.pending, None
        plans = self.inner.info().get("plans", 0) if pending is not None else 0
        t0 = time.process_time()
        command = self.inner.step(t, q, observation, goal)
        spent = time.process_time() - t0
        if pending is not None and self.inner.info().get("plans", 0) == plans:
            self.ticks.append(pending + spent)
        return command

    def info(self) -> dict[str, Any]:
        return self.inner.info()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenarios", nargs="*", default=list(DEFAULT), help="scenario references")
    parser.add_argument("--settings", default="{}", help='ompl-replan settings as JSON, e.g. \'{"unknown": "free"}\'')
    args = parser.parse_args()
    settings = json.loads(args.settings)
    every = []
    for ref in args.scenarios:
        timer = FrameTimer(make_controller("ompl-replan", **settings))
        record = run_scenario(load_scenario(ref), timer, settings=RunSettings(timing="ideal"))
        ms = np.array(timer.ticks) * 1e3
        every.append(ms)
        print(
            f"{ref:48s} {record.status:9s} frames {len(ms):4d}  median {np.median(ms):6.2f}  "
            f"p90 {np.percentile(ms, 90):6.2f} ms  over {PERIOD_MS:g} ms: {np.mean(ms > PERIOD_MS):4.0%}",
            flush=True,
        )
    ms = np.concatenate(every)
    print(
        f"{'all':48s} {'':9s} frames {len(ms):4d}  median {np.median(ms):6.2f}  "
        f"p90 {np.percentile(ms, 90):6.2f} ms  over {PERIOD_MS:g} ms: {np.mean(ms > PERIOD_MS):4.0%}"
    )


if __name__ == "__main__":
    main()

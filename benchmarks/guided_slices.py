"""What one tick of ``matrix-field-guided`` costs, by the work slice it ran: CPU time per tick.

    python benchmarks/guided_slices.py                      # the six default scenarios
    python benchmarks/guided_slices.py --scenarios "dynamic-tune:*_crossing_fast_*" --set plan_checks_per_tick=100

Each scenario runs in this process with ``timing = "ideal"`` (no compute charged, so every run
makes the same ticks on any machine) and each tick's CPU time (``time.thread_time``: ``update``
when a frame arrives, then ``step``) is recorded with the slice the step ran, read from the
controller's job: a plan's geometry (truth: the scene's checker; depth: the grid's occupied cells,
the cells the arm touches, the octrees, their checker), a plan's search (RRT-Connect slices of
``plan_checks_per_tick`` checks) or shortening, a frame check's geometry or its configurations,
or no slice (the control law alone). Printed per sensing model and slice: ticks, median, p99 and
largest CPU time [ms], and the checks per search slice (median, largest). One numba thread and one
BLAS thread: one core, as the benchmark charges it.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"  # before numpy and numba are imported: one core

import argparse  # noqa: E402
import time  # noqa: E402
from collections import defaultdict  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

import planbench  # noqa: E402
from planbench.problem import Goal  # noqa: E402
from planbench.reactive.controller import Observation  # noqa: E402
from planbench.reactive.runner import RunSettings, run_scenario  # noqa: E402
from planbench_plugins.controllers.matrix_field_guided import MatrixFieldGuidedController  # noqa: E402

SCENARIOS = [
    "dynamic:panda_crossing_fast_depth/0001",
    "dynamic:ur5_reaching_fast_depth/0004",
    "dynamic:xarm7_sliding_fast_depth/0007",
    "dynamic:panda_crossing_fast_truth/0001",
    "dynamic:ur5_reaching_fast_truth/0004",
    "dynamic:xarm7_sliding_fast_truth/0007",
]


def stage(job: Any, kind: str) -> str:
    """The slice a job's last ``next`` ran, from the locals of its generator where it stopped."""
    frame = getattr(job, "gi_frame", None)
    if frame is None:
        return f"{kind}: last slice"  # it ended in this tick
    where = frame.f_locals
    if kind == "plan":
        query = where.get("query")
        return "plan: geometry" if query is None else "plan: search" if query.path is None else "plan: shortening"
    return "check: configurations" if "rest" in where else "check: geometry"


def query_checks(job: Any) -> int | None:
    """The checks of the plan's query so far (None: no query yet)."""
    frame = getattr(job, "gi_frame", None)
    query = frame.f_locals.get("query") if frame is not None else None
    return None if query is None else int(query.checks)


class Timed(MatrixFieldGuidedController):
    """The controller, each tick's CPU time and slice recorded."""

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        super().reset(q, rng)
        self.ticks: list[tuple[str, float, int]] = []
        self._update = 0.0
        self._before = 0  # the query's checks after the last tick

    def update(self, observation: Observation) -> None:
        t0 = time.thread_time()
        super().update(observation)
        self._update = time.thread_time() - t0

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Goal) -> np.ndarray:
        slices = self.stats["slices"]
        t0 = time.thread_time()
        out = super().step(t, q, observation, goal)
        cpu = time.thread_time() - t0 + self._update
        self._update = 0.0
        where, checks = "control only", 0
        if self.stats["slices"] > slices:
            where = stage(self.job, self.job_kind)
            after = query_checks(self.job)
            if where == "plan: search" and after is not None:
                checks = after - self._before
        self._before = query_checks(self.job) or 0
        self.ticks.append((where, cpu, checks))
        return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=SCENARIOS)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a controller setting")
    args = parser.parse_args()
    settings: dict[str, Any] = {}
    for item in args.set:
        key, _, value = item.partition("=")
        settings[key] = int(value) if value.lstrip("-").isdigit() else float(value)
    rows: dict[tuple[str, str], list[float]] = defaultdict(list)
    search_checks: dict[str, list[int]] = defaultdict(list)
    for selector in args.scenarios:
        for scenario in planbench.load_scenarios(selector):
            controller = Timed(**settings)
            record = run_scenario(scenario, controller, settings=RunSettings(timing="ideal"))
            sensing = scenario.sensing.model
            for where, cpu, checks in controller.ticks:
                rows[(sensing, where)].append(1e3 * cpu)
                if where == "plan: search" and checks:
                    search_checks[sensing].append(checks)
            print(
                f"{scenario.name}: {record.status}, {len(controller.ticks)} ticks, {controller.info()['paths']} paths"
            )
    print()
    print("| sensing | slice | ticks | median [ms] | p99 [ms] | largest [ms] |")
    print("| --- | --- | --- | --- | --- | --- |")
    for (sensing, where), ms in sorted(rows.items()):
        v = np.array(ms)
        print(f"| {sensing} | {where} | {len(v)} | {np.median(v):.2f} | {np.percentile(v, 99):.2f} | {v.max():.2f} |")
    for sensing, counts in sorted(search_checks.items()):
        print(f"{sensing}: checks per search slice median {np.median(counts):.0f}, largest {max(counts)}")


if __name__ == "__main__":
    main()

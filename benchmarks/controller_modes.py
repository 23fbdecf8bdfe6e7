"""Full or lazy matrix field in the matrix-field controller: cost per frame and per step.

    NUMBA_NUM_THREADS=1 python benchmarks/controller_modes.py

The first problem of each MotionBenchMaker family seen by the benchmark's sensors at 2 cm (truth,
and the default depth camera); per mode, the median of a frame (``update`` plus the first step
after it) and of a step, and the compute of one second of motion at 30 frames/s and 100 ticks/s
(docs/writing-a-controller.md, "Full or lazy field").
"""

import time

import numpy as np

import planbench
from planbench.reactive import ControlTask, SensingSettings
from planbench.reactive.sensing import Sensor
from planbench.registry import make_controller

families = ("box", "bookshelf_tall", "bookshelf_small", "bookshelf_thin", "cage", "table_pick", "table_under_pick")
for family in families:
    problem = planbench.load_problems(f"mbm:{family}/0001")[0]
    robot = problem.robot
    task = ControlTask(robot, problem.start, problem.goal, problem.tolerances, period=0.01)
    for model in ("truth", "depth"):
        sensor = Sensor(SensingSettings(model=model, resolution=0.02), robot)  # the benchmark's grid
        obs = sensor.capture(problem.scene, problem.start, 0.0, 0, np.random.default_rng(0))
        for mode in ("full", "lazy"):
            c = make_controller("matrix-field", field_mode=mode)
            c.setup(task)
            c.reset(problem.start, np.random.default_rng(0))
            frame, step = [], []
            for _ in range(20):  # a frame: update + the first step after it; then 9 more steps
                t0 = time.perf_counter()
                c.update(obs)
                c.step(0.0, problem.start, obs, problem.goal)
                frame.append(time.perf_counter() - t0)
                for _ in range(9):
                    t0 = time.perf_counter()
                    c.step(0.0, problem.start, obs, problem.goal)
                    step.append(time.perf_counter() - t0)
            f, s = np.median(frame[3:]) * 1e3, np.median(step[27:]) * 1e6
            block = c.field.repulsion(obs.grid, surfaces=obs.points is not None).grid.shape
            print(
                f"{family} {model} {block} {mode}: frame {f:.1f} ms, step {s:.0f} us, "
                f"{30 * f + 100 * s / 1e3:.0f} ms per second"
            )

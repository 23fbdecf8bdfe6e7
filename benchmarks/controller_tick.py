"""Can a controller run the Panda at 1 kHz on one core? Tick times with the field update included.

    python benchmarks/controller_tick.py                 # 2 s of control at 1 kHz, 30 Hz depth frames
    python benchmarks/controller_tick.py --seconds 4 --sensing truth
    python benchmarks/controller_tick.py --controllers mppi --rate 100 --clock cpu   # mppi at 100 Hz
    python benchmarks/controller_tick.py --controllers matrix-field-guided --settings '{"slice_cpu_share": 0.15}'

A 128^3 grid (2 cm cells, a 2.56 m cube around the base) is observed at 30 Hz from the scenario
``dynamic:panda_swinging_fast_<sensing>/0001`` (a forearm swinging across the Panda's path at
1 m/s), with the arm's configuration of each frame taken from a closed-loop run of the controller;
frames are captured before timing starts, so only the controller is timed. The controller is then
stepped at 1 kHz along that run: a tick is ``update(frame)`` when a new frame arrives plus
``step``. Printed per controller: tick time median and p99, the share of ticks over 1 ms, the
field update per frame (median) and, per frame, the ratio of the EDT controller's update to each
other controller's on the same frames (median of the per-frame ratios). One numba thread
(``NUMBA_NUM_THREADS=1``) and one BLAS thread: one core.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"  # before numpy and numba are imported: one core

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

import planbench  # noqa: E402
from planbench.reactive.controller import ControlTask  # noqa: E402
from planbench.reactive.runner import RunSettings, run_scenario  # noqa: E402
from planbench.reactive.sensing import Sensor  # noqa: E402
from planbench.registry import make_controller  # noqa: E402

CELLS, RESOLUTION = 128, 0.02
RATE, FRAME_RATE = 1000.0, 30.0


def frames_of(scenario, seconds: float, rate: float = RATE) -> tuple[list, np.ndarray]:
    """Sensor frames at 30 Hz over ``seconds`` along a closed-loop run of matrix-field (the arm's
    configuration at each frame), on the 128^3 grid; and the run's configurations per 1 ms tick."""
    half = CELLS * RESOLUTION / 2
    bounds = (np.full(3, -half) + [0, 0, half - 0.4], np.full(3, half) + [0, 0, half - 0.4])
    sensing = replace(scenario.sensing, resolution=RESOLUTION)
    sensor = Sensor(sensing, scenario.problem.robot, bounds=bounds)
    assert (
        sensor.capture(scenario.scene_at(0.0), scenario.problem.start, 0.0, 0, np.random.default_rng(0)).grid.shape
        == (CELLS,) * 3
    )
    run = run_scenario(
        replace(scenario, control_rate=rate, horizon=seconds),
        make_controller("matrix-field"),
        settings=RunSettings(timing="ideal", check_collisions=False),
    )
    ticks = np.linspace(0.0, seconds, int(seconds * rate), endpoint=False)
    qs = np.array([run.path[min(np.searchsorted(run.times, t), len(run.path) - 1)] for t in ticks])
    rng = np.random.default_rng(0)
    frames = []
    for j in range(int(seconds * FRAME_RATE)):
        t = j / FRAME_RATE
        q = qs[min(int(t * rate), len(qs) - 1)]
        frames.append(sensor.capture(scenario.scene_at(t), q, t, j, rng))
    return frames, qs


def tick_times(
    name: str,
    scenario,
    frames: list,
    qs: np.ndarray,
    rate: float = RATE,
    clock=time.perf_counter,
    settings: dict | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(tick times, update times) [s] of controller ``name`` (with ``settings``) stepped at ``rate``
    [Hz] along ``qs``."""
    p = scenario.problem
    c = make_controller(name, **(settings or {}))
    c.setup(ControlTask(p.robot, p.start, p.goal, p.tolerances, 1.0 / rate, scenario.name))
    c.reset(np.array(p.start), np.random.default_rng(0))
    c.update(frames[0])
    c.step(0.0, qs[0].copy(), frames[0], p.goal)  # warm-up: compiled code, first buffers
    ticks, updates = [], []
    frame_every = rate / FRAME_RATE
    latest = frames[0]
    for k, q in enumerate(qs):
        j = int(k / frame_every)
        t0 = clock()
        if j < len(frames) and frames[j] is not latest:
            latest = frames[j]
            c.update(latest)
            updates.append(clock() - t0)
        c.step(k / rate, q.copy(), latest, p.goal)
        ticks.append(clock() - t0)
    return np.array(ticks), np.array(updates)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="control time simulated [s]")
    parser.add_argument("--sensing", choices=("depth", "truth"), default="depth")
    parser.add_argument("--controllers", default="matrix-field,edt-field", help="comma-separated names")
    parser.add_argument("--rate", type=float, default=RATE, help="control rate [Hz]")
    parser.add_argument(
        "--clock", choices=("wall", "cpu"), default="wall", help="cpu: this process's CPU time (a loaded machine)"
    )
    parser.add_argument("--settings", default="{}", help="JSON object of settings given to every controller")
    args = parser.parse_args()
    settings = json.loads(args.settings)
    if not isinstance(settings, dict):
        parser.error("--settings must be a JSON object, e.g. '{\"slice_cpu_share\": 0.15}'")
    scenario = planbench.load_scenarios(f"dynamic:panda_swinging_fast_{args.sensing}/0001")[0]
    frames, qs = frames_of(scenario, args.seconds, args.rate)
    period = 1.0 / args.rate
    print(
        f"{scenario.name}: {len(qs)} ticks at {args.rate:g} Hz, {len(frames)} frames of a {CELLS}^3 grid "
        f"({RESOLUTION} m cells), one core"
    )
    over = f"> {period * 1e3:g} ms"
    print(f"{'controller':<14} {'tick median':>12} {'tick p99':>10} {over:>9} {'update/frame':>13}")
    updates = {}
    for name in args.controllers.split(","):
        clock = time.process_time if args.clock == "cpu" else time.perf_counter
        ticks, upd = tick_times(name, scenario, frames, qs, args.rate, clock, settings)
        updates[name] = upd
        print(
            f"{name:<14} {np.median(ticks) * 1e3:>9.3f} ms {np.percentile(ticks, 99) * 1e3:>7.3f} ms "
            f"{np.mean(ticks > period):>8.1%} {np.median(upd) * 1e3:>10.3f} ms"
        )
    if "edt-field" not in updates:
        return
    for name, upd in updates.items():
        if name == "edt-field":
            continue
        n = min(len(upd), len(updates["edt-field"]))
        ratio = updates["edt-field"][:n] / upd[:n]
        print(
            f"field update per frame, edt-field / {name} on the same {n} frames: "
            f"median {np.median(ratio):.1f}x [q1 {np.percentile(ratio, 25):.1f}, q3 {np.percentile(ratio, 75):.1f}]"
        )


if __name__ == "__main__":
    main()

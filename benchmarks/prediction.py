"""What obstacle prediction costs per frame and how close its velocities are to the truth.

    python benchmarks/prediction.py                                      # six crossing and swinging scenarios
    python benchmarks/prediction.py --scenarios "dynamic-tune:*_pair_fast_depth"

Each scenario runs in this process with ``matrix-field`` (``prediction = "none"``: the arm's
motion does not depend on the predictor) and ``timing = "ideal"``; every delivered frame also goes
through a :class:`~planbench_plugins.controllers.prediction.MotionPredictor` with its default
settings, timed with ``time.thread_time`` (CPU time, one thread, as the benchmark charges it).
The truth is read here only to judge: each trusted track is matched to the nearest moving
obstacle present at the frame's capture (its reference point within 0.2 m of the track's centroid
plus the obstacle's size) and its velocity compared with that obstacle's (a finite difference of
its pose; a swinging obstacle's reference point is its pivot's image, so its error is an upper
bound). Printed: per scenario the frames, the predictor's median, p99 and largest CPU time per
frame [ms], the frames with a trusted track, how many of those tracks matched an obstacle, and the
median speed error [m/s] and direction error [deg] of the matched ones. One numba thread and one
BLAS thread.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"  # before numpy and numba are imported: one core

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

import planbench  # noqa: E402
from planbench.reactive.controller import Observation  # noqa: E402
from planbench.reactive.runner import RunSettings, run_scenario  # noqa: E402
from planbench.registry import make_controller  # noqa: E402
from planbench_plugins.controllers.prediction import MotionPredictor, PredictionSettings  # noqa: E402

SCENARIOS = [
    "dynamic-tune:*_crossing_fast_depth",
    "dynamic-tune:*_swinging_fast_depth",
]


def obstacle_states(scenario: Any, t: float) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Position [m], velocity [m/s] and a size [m] of each moving obstacle present at ``t``."""
    out = []
    for m in scenario.moving:
        if not (m.present(t) and m.present(t + 0.01)):
            continue
        a, b = m.at(t), m.at(t + 0.01)
        size = max(list(a.size or []) + [a.radius or 0.0, (a.length or 0.0) / 2])
        out.append((np.asarray(a.position, float), (np.asarray(b.position, float) - a.position) / 0.01, size))
    return out


def measure(scenario: Any) -> dict[str, Any]:
    controller = make_controller("matrix-field")
    predictor = MotionPredictor(PredictionSettings(prediction="swept"))
    costs: list[float] = []
    matched: list[tuple[float, float]] = []
    frames_with, tracks_total = 0, 0
    update = controller.update

    def observed(observation: Observation) -> None:
        nonlocal frames_with, tracks_total
        t0 = time.thread_time()
        p = predictor.observe(observation)
        costs.append(time.thread_time() - t0)
        trusted = [tr for tr in p.tracks if tr.velocity is not None and tr.last_seen == observation.time]
        frames_with += bool(trusted)
        truths = obstacle_states(scenario, observation.time)
        for tr in trusted:
            tracks_total += 1
            assert tr.velocity is not None
            near = [(float(np.linalg.norm(pos - tr.centroids[-1])) - size, vel) for pos, vel, size in truths]
            near = [x for x in near if x[0] < 0.2]
            if not near:
                continue
            vel = min(near, key=lambda x: x[0])[1]
            speed_error = abs(float(np.linalg.norm(tr.velocity)) - float(np.linalg.norm(vel)))
            cos = float(tr.velocity @ vel) / max(1e-9, float(np.linalg.norm(tr.velocity) * np.linalg.norm(vel)))
            matched.append((speed_error, math.degrees(math.acos(max(-1.0, min(1.0, cos))))))
        update(observation)

    controller.update = observed  # type: ignore[method-assign]
    run_scenario(scenario, controller, seed=0, settings=RunSettings(timing="ideal"))
    ms = np.array(costs[1:]) * 1e3  # the first frame only allocates
    err = np.array(matched) if matched else np.full((1, 2), np.nan)
    return {
        "frames": len(costs),
        "median_ms": float(np.median(ms)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
        "frames_with_track": frames_with,
        "tracks": tracks_total,
        "matched": len(matched),
        "speed_error": float(np.median(err[:, 0])),
        "direction_error": float(np.median(err[:, 1])),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenarios", nargs="+", default=SCENARIOS)
    args = parser.parse_args()
    print(
        "| scenario | frames | median [ms] | p99 [ms] | largest [ms] | frames with a track | tracks matched | "
        "speed error [m/s] | direction error [deg] |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for selector in args.scenarios:
        for scenario in planbench.load_scenarios(selector):
            r = measure(scenario)
            print(
                f"| {scenario.name} | {r['frames']} | {r['median_ms']:.2f} | {r['p99_ms']:.2f} | {r['max_ms']:.2f} | "
                f"{r['frames_with_track']} | {r['matched']}/{r['tracks']} | {r['speed_error']:.2f} | "
                f"{r['direction_error']:.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()

"""The 1 kHz question across the process boundary: a controller in its own confined process, its
compute charged as the benchmark charges it (CPU time of its process, read from outside).

    python benchmarks/controller_tick_isolated.py [--seconds 2] [--repeat 3] [--controllers matrix-field edt-field]

Each controller runs closed-loop (:func:`planbench.reactive.run_isolated`) on
``dynamic:panda_swinging_fast_<sensing>/0001`` (a forearm swinging across the Panda's path at
1 m/s) at 1 kHz for ``--seconds`` of simulated time, frames at 30 Hz on the scenario's grid (2 cm
cells, 142^3 around the Panda), ``timing = "measured"``, one thread, collision checks off (they
cost the simulation, not the controller). Printed per sensing model and controller, medians over
``--repeat`` runs: the charged time of a controller turn (update included) median and p99, the share
of turns over 1 ms, the charged update per frame, and the hand-off (wall-clock round trip less the
charge) median and p99 per call.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from planbench.reactive.isolated import run_isolated
from planbench.reactive.runner import RunSettings
from planbench.reactive.sets import load_scenario


def one(scenario, controller: str) -> dict[str, float]:
    run = run_isolated(scenario, controller, settings=RunSettings(check_collisions=False))
    ticks = run.record.measured[np.isfinite(run.record.measured)]
    handoff = np.asarray(run.handoff)
    return {
        "median": float(np.median(ticks)),
        "p99": float(np.percentile(ticks, 99)),
        "over": float(np.mean(ticks > 1e-3)),
        "update": float(np.median(run.record.field_update_times)),
        "handoff": float(np.median(handoff)),
        "handoff_p99": float(np.percentile(handoff, 99)),
        "turns": float(len(ticks)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--controllers", nargs="+", default=["matrix-field", "edt-field"])
    args = ap.parse_args()
    print(
        "| sensing | controller | tick median | tick p99 | turns over 1 ms | update per frame "
        "| hand-off median | hand-off p99 |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for sensing in ("depth", "truth"):
        base = load_scenario(f"dynamic:panda_swinging_fast_{sensing}/0001")
        scenario = replace(base, control_rate=1000.0, horizon=args.seconds)
        for controller in args.controllers:
            runs = [one(scenario, controller) for _ in range(args.repeat)]
            m = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
            print(
                f"| {sensing} | `{controller}` | {m['median'] * 1e3:.3f} ms | {m['p99'] * 1e3:.3f} ms | "
                f"{m['over'] * 100:.1f} % | {m['update'] * 1e3:.3f} ms | {m['handoff'] * 1e6:.0f} µs | "
                f"{m['handoff_p99'] * 1e6:.0f} µs |"
            )


if __name__ == "__main__":
    main()

"""How the depth scenarios' camera rig and map sensor model were chosen, on ``dynamic-tune``.

    python benchmarks/camera_rig.py rig-variants/          # writes the variants, prints the commands
    python benchmarks/camera_rig.py rig-variants/ --coverage

Writes the fast depth scenarios of ``dynamic-tune`` (24: 3 base problems x 8 behaviours) four
times into folders of ``rig-variants/``, differing only in sensing: the front camera alone or with
the camera over the shoulder (:mod:`planbench.reactive.generator`), the map's ``hit`` 0.7
(OctoMap's) or 0.9 (planbench's default); plus a suite per folder running ``ompl-replan``, the
controller whose depth result is to come within reach of its truth result, and a suite of the same
scenarios with truth sensing. Prints the commands.

``--coverage`` prints, per base problem and rig, the share of the static scene's surface cells near
the certificate's path (within 0.15 m of the arm's cells along it) that the map shows occupied at
some frame while the arm follows the certificate: what each rig lets a controller see of the
scene it has to pass.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
from scipy import ndimage

from planbench.geometry.occupancy_map import MapSettings
from planbench.reactive.body import ArmBody
from planbench.reactive.scenario import Scenario, SensingSettings
from planbench.reactive.sensing import Sensor
from planbench.reactive.sets import load_scenarios

RIGS = {"front": 1, "front+shoulder": 2}
HITS = (0.7, 0.9)
SUITE = """[suite]
name = "rig-{label}"
description = "ompl-replan on dynamic-tune fast depth: {label}"
scenarios = ["{folder}"]
seeds = [0]
timing = "measured"
time_limit = 300.0

[[controllers]]
controller = "ompl-replan"
"""


def variant(s: Scenario, cameras: int, hit: float) -> Scenario:
    """``s`` seen by its first ``cameras`` cameras with the map's ``hit`` probability."""
    sensing = dataclasses.replace(s.sensing, cameras=s.sensing.cameras[:cameras], map=MapSettings(hit=hit))
    return dataclasses.replace(s, sensing=sensing)


def coverage(s: Scenario, reach: float = 0.15) -> float:
    """The share of static surface cells near the certificate's path the map saw occupied (module docstring)."""
    assert s.certificate is not None
    truth = Sensor(SensingSettings("truth", rate=30.0), s.problem.robot)
    static = truth.truth_grid(s.problem.scene).data >= 0.5
    surface = static & ~ndimage.binary_erosion(static, border_value=0)
    sensor = Sensor(s.sensing, s.problem.robot, bounds=truth.bounds)
    body = ArmBody(s.problem.robot, truth.bounds[0], static.shape, s.sensing.resolution)
    swept, seen = np.zeros(static.shape, bool), np.zeros(static.shape, bool)
    cert, rng = s.certificate, np.random.default_rng(0)
    for t in np.arange(0.0, cert.time_to_goal + 1e-9, 1.0 / s.sensing.rate):
        q = np.array([np.interp(t, cert.times, cert.path[:, j]) for j in range(cert.path.shape[1])])
        body.mark(swept, q)
        seen |= sensor.capture(s.scene_at(t), q, t, 0, rng).grid.data >= 0.5
    r = round(reach / s.sensing.resolution)
    ball = np.linalg.norm(np.mgrid[-r : r + 1, -r : r + 1, -r : r + 1], axis=0) <= r
    near = surface & ndimage.binary_dilation(swept, ball)
    return float((seen & near).sum() / max(int(near.sum()), 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("--coverage", action="store_true")
    args = parser.parse_args()
    scenarios = load_scenarios("dynamic-tune:*_fast_depth")
    if args.coverage:
        for s in [s for s in scenarios if s.metadata["behaviour"] == "sliding"]:  # one per base problem
            shares = {rig: coverage(variant(s, n, 0.9)) for rig, n in RIGS.items()}
            print(s.metadata["base"], "  ".join(f"{rig}: {100 * v:.0f} %" for rig, v in shares.items()))
        return
    for rig, n in RIGS.items():
        for hit in HITS:
            label = f"{rig}-hit{hit}"
            folder = args.out / label
            folder.mkdir(parents=True, exist_ok=True)
            for s in scenarios:
                variant(s, n, hit).save(folder / (s.name.replace(":", "_").replace("/", "_") + ".json"))
            suite = args.out / f"{label}.toml"
            suite.write_text(SUITE.format(label=label, folder=folder.resolve()))
            print(f"planbench bench --suite {suite} --out {args.out / label}.db --jobs 2")
    truth = args.out / "truth.toml"
    truth.write_text(SUITE.format(label="truth", folder="dynamic-tune:*_fast_truth"))
    print(f"planbench bench --suite {truth} --out {args.out / 'truth'}.db --jobs 2   # the truth reference")


if __name__ == "__main__":
    main()

"""The push that keeps the arm out of itself: a repulsion between the robot's own links.

A field built from the scene sees only the scene, so nothing stops the pose task from folding the
arm into itself (on a 6-joint arm, or after an escape, most of all). This wraps a planner's
:class:`~.loop.Repulsion`: for every pair of the robot's collision geometries that may touch (the
collision model's pairs: the SRDF's exclusions removed, pairs on one joint left out) and lies
closer than ``influence``, coal's distance ``d``, witness points ``a`` and ``b`` and the unit
normal ``n`` from the first body to the second (:class:`.distances.DistanceModel`, meshes as their
convex hulls, so ``d`` never overestimates the gap) give two more pushes, in the units of the
field's (a speed [m/s]):

    f_a = -m(d) n  at a (moved by the first body's joints),   f_b = +m(d) n  at b (the second's)
    m(d) = gain * speed_max * ((influence - d) / influence)^2    (0 beyond ``influence``)

so the push is C1 at the influence distance and reaches ``gain`` times the cruising speed at
contact. While no pair is within ``influence``, the distances are asked only every ``every``
steps (a query costs about 40 us, six times a whole matrix-field step; in ``every`` steps a link
moves a few millimetres, well inside the influence distance); once a pair is near, every step.
The pushes go through the same hierarchy as the field's (null space, or priority rows: with the
default gain of 3 a pair at contact is a fully active row). Their points carry joint id ``-1``,
so they never count as the tool's.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planbench_plugins.ik_loop.distances import DistanceModel

__all__ = ["SelfCollisionPush"]


class SelfCollisionPush:
    """``inner``'s repulsion plus the self-collision pushes of the module docstring."""

    def __init__(
        self, inner: Any, robot: Any, scene: Any, *, influence: float, gain: float, speed_max: float, every: int = 4
    ) -> None:
        self.inner = inner
        self.every = int(every)
        self._quiet = 0  # steps left before the distances are asked again (none was near)
        self.gain = inner.gain
        self.distances = DistanceModel(robot, scene, influence, self_pairs=True, obstacle_pairs=False)
        self.influence, self.push_gain, self.speed_max = float(influence), float(gain), float(speed_max)
        self.pairs_near = 0
        """Pairs within the influence distance at the last call."""

    def restart(self) -> None:
        """Ask the distances on the next call (a new query starts where the last one did not end)."""
        self._quiet = 0

    @property
    def n_pairs(self) -> int:
        return self.distances.n_pairs

    def forces(self, kin: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        points, F, support, joint = self.inner.forces(kin)
        if self._quiet > 0:
            self._quiet -= 1
            return points, F, support, joint
        pairs = self.distances.near(kin.model, kin.data)
        self.pairs_near = m = len(pairs)
        if not m:
            self._quiet = self.every - 1
            return points, F, support, joint
        u = np.clip((self.influence - pairs.distance) / self.influence, 0.0, None)
        push = (self.push_gain * self.speed_max * u * u)[:, None] * pairs.normal
        return (
            np.concatenate((points, pairs.point, pairs.other_point)),
            np.concatenate((F, -push, push)),
            np.concatenate((support, pairs.support, pairs.other_support)),
            np.concatenate((joint, np.full(2 * m, -1, dtype=joint.dtype))),
        )

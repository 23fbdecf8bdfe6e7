"""The repulsion of a controller: a fixed object for the IK loop, its source replaced every frame.

An IK-loop planner binds its repulsion once, in ``setup`` (and wraps it in the self-collision
push). A controller sees a new occupancy grid at the sensor rate, so the loop gets this holder
instead: :attr:`LiveRepulsion.source` is swapped on every ``update(observation)`` and ``forces``
asks whichever source is current. Before the first frame, and after ``reset``, the source is
:class:`~planbench_plugins.ik_loop.ZeroRepulsion`: the controller knows of no obstacle.
"""

from __future__ import annotations

import numpy as np

from planbench_plugins.ik_loop import ArmKinematics, Repulsion, ZeroRepulsion

__all__ = ["LiveRepulsion"]


class LiveRepulsion:
    """A :class:`~planbench_plugins.ik_loop.Repulsion` that delegates to :attr:`source`.

    Sources on the loop's control points (the grid fields: ``points is kin.points``) have their
    push copied into one buffer owned here, so the loop sees the same arrays every step whatever
    the source and keeps its compiled step bound to them (a new array would send every step
    through numba's type dispatch). Other sources (per-link witness points, the self-collision
    push's extra points) pass through as they are.
    """

    def __init__(self, source: Repulsion | None = None) -> None:
        self.source: Repulsion = source if source is not None else ZeroRepulsion()
        self._F = np.zeros((0, 3))

    @property
    def gain(self) -> float:
        """The current source's gain (in its own units; 0 without a source)."""
        return float(self.source.gain)

    def replace(self, source: Repulsion | None) -> None:
        """Use ``source`` from the next step on (None: no repulsion)."""
        self.source = source if source is not None else ZeroRepulsion()

    def forces(self, kin: ArmKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        points, F, support, joint = self.source.forces(kin)
        if points is kin.points and support is kin.support:
            if self._F.shape != F.shape:
                self._F = np.zeros_like(F, dtype=float)
            self._F[:] = F
            return kin.points, self._F, kin.support, kin.cp_joint
        return points, F, support, joint

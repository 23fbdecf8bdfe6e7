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
steps (in ``every`` steps a link moves a few millimetres, well inside the influence distance);
once a pair is near, every step. Asking starts with bounding capsules, one per geometry (one
compiled pass over the pairs, straight from the joint placements the step's kinematics already
hold: well under a microsecond); only the pairs whose capsules come within ``influence`` go to
coal (a few microseconds each, plus pinocchio's geometry placements). Far from itself, the arm
costs the step the capsules' pass and nothing else. Without numba, bounding spheres (looser, in
numpy) cull instead; either way coal measures every pair that may lie within ``influence``, so
the pushes are the same.
The pushes go through the same hierarchy as the field's (null space, or priority rows: with the
default gain of 3 a pair at contact is a fully active row). Their points carry joint id ``-1``,
so they never count as the tool's.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np

from planbench_plugins.ik_loop import fast
from planbench_plugins.ik_loop.distances import DistanceModel

__all__ = ["SelfCollisionPush"]


class SelfCollisionPush:
    """``inner``'s repulsion plus the self-collision pushes of the module docstring.

    ``compiled``: cull with bounding capsules in the numba kernel (``_compiled.capsules_within``),
    else with :meth:`DistanceModel.self_candidates` (spheres, numpy); default: when numba is
    installed. Either keeps every pair within the influence distance: the same pushes.
    """

    def __init__(
        self,
        inner: Any,
        robot: Any,
        scene: Any,
        *,
        influence: float,
        gain: float,
        speed_max: float,
        every: int = 4,
        compiled: bool | None = None,
    ) -> None:
        self.inner = inner
        self.every = int(every)
        self._quiet = 0  # steps left before the distances are asked again (none was near)
        self.gain = inner.gain
        self.distances = dm = DistanceModel(robot, scene, influence, self_pairs=True, obstacle_pairs=False)
        self.influence, self.push_gain, self.speed_max = float(influence), float(gain), float(speed_max)
        self.compiled = fast.have_numba() if compiled is None else bool(compiled)
        self.pairs_near = 0
        """Pairs within the influence distance at the last ask."""
        self.pairs_culled = 0
        """Pairs whose bounding volumes came within the influence distance at the last ask (the
        ones handed to coal)."""
        first, second = dm.pair_bodies
        segment, radius = dm.body_segment, dm.body_capsule_radius
        reach = radius + 0.5 * np.linalg.norm(segment[:, 1] - segment[:, 0], axis=1)  # spheres around the capsules
        self._cull_args = (dm.body_joint, segment, radius, reach, first, second, dm.influence)
        self._segment = np.empty((dm.n_robot, 2, 3))
        self._candidates = np.empty(dm.n_pairs, dtype=np.intp)
        self._bound: tuple[Any, Callable[[], int]] | None = None  # (kinematics, its bound cull)
        P = dm.n_pairs  # what coal measured at the last ask: pair, distance, two witness points, normal
        self._pairs = (np.empty(P, dtype=np.intp), np.empty(P), np.empty((P, 3)), np.empty((P, 3)), np.empty((P, 3)))
        self._out: dict[int, tuple[np.ndarray, ...]] = {}  # reused output buffers, by the inner point count

    def restart(self) -> None:
        """Ask the distances on the next call (a new query starts where the last one did not end)."""
        self._quiet = 0

    @property
    def n_pairs(self) -> int:
        return self.distances.n_pairs

    def candidates(self, kin: Any) -> np.ndarray:
        """The pairs (indices) whose bounding capsules (spheres without numba) lie within the influence distance at
        ``kin``'s configuration (a view of a reused buffer)."""
        Rs, ts = kin.joint_placements
        if not self.compiled:
            found = self.distances.self_candidates(Rs, ts)
            self._candidates[: len(found)] = found
            return self._candidates[: len(found)]
        if self._bound is None or self._bound[0] is not kin:
            args = (Rs, ts, *self._cull_args, self._segment, self._candidates)
            self._bound = (kin, functools.partial(fast.bind(fast.compiled().capsules_within, *args), *args))
        return self._candidates[: self._bound[1]()]

    def forces(self, kin: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        inner = self.inner.forces(kin)
        if self._quiet > 0:  # the common step: nothing near at the last ask
            self._quiet -= 1
            return inner  # type: ignore[no-any-return]
        points, F, support, joint = inner
        near = self.candidates(kin)
        self.pairs_culled = len(near)
        m = 0
        if len(near):
            m = self.distances.measure(kin.model, kin.data, near, *self._pairs)
        self.pairs_near = m
        if not m:
            self._quiet = self.every - 1
            return points, F, support, joint
        return self._with_pushes(points, F, support, joint, m)

    def _with_pushes(
        self, points: np.ndarray, F: np.ndarray, support: np.ndarray, joint: np.ndarray, m: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``inner``'s arrays followed by the pushes on the ``m`` near pairs' first bodies, then on
        their second bodies, written into buffers kept for this point count (views returned)."""
        N = len(points)
        pair, distance, point, other_point, normal = (a[:m] for a in self._pairs)
        out = self._out.get(N)
        if out is None:
            P, n = self.distances.n_pairs, support.shape[1]
            out = self._out[N] = (
                np.empty((N + 2 * P, 3)),
                np.empty((N + 2 * P, 3)),
                np.empty((N + 2 * P, n)),
                np.full(N + 2 * P, -1, dtype=joint.dtype),
            )
        o_points, o_F, o_support, o_joint = out
        o_points[:N], o_F[:N], o_support[:N], o_joint[:N] = points, F, support, joint
        o_points[N : N + m], o_points[N + m : N + 2 * m] = point, other_point
        first, second = self.distances.pair_bodies
        body_support = self.distances.body_support
        np.take(body_support, first[pair], axis=0, out=o_support[N : N + m])
        np.take(body_support, second[pair], axis=0, out=o_support[N + m : N + 2 * m])
        u = np.clip((self.influence - distance) / self.influence, 0.0, None)
        np.multiply((self.push_gain * self.speed_max * u * u)[:, None], normal, out=o_F[N + m : N + 2 * m])
        np.negative(o_F[N + m : N + 2 * m], out=o_F[N : N + m])
        k = N + 2 * m
        return o_points[:k], o_F[:k], o_support[:k], o_joint[:k]

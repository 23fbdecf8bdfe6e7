"""Per-step kinematics with preallocated buffers: one pinocchio pass, everything else vectorized.

``update(q)`` runs ``pinocchio.computeJointJacobians`` (forward kinematics and the spatial
Jacobian ``S``, WORLD convention) and ``updateFramePlacement`` for the goal frame, then reads the
joint placements through views that pinocchio updates in place (no per-joint Python call) and
computes all control-point positions in one batched product. Control-point Jacobians are never
formed on the hot path: :func:`~planbench_plugins.ik_loop.tasks.repulsion_joint_velocity`
applies their transposes from ``S`` directly.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planbench_plugins.ik_loop.control_points import ControlPoints

__all__ = ["ArmKinematics"]


class ArmKinematics:
    """Kinematics of one robot for one goal frame and one set of control points. Not thread-safe.

    After :meth:`update`: ``p`` (3,) and ``R`` (3, 3) goal-frame pose, ``J`` (6, n) its Jacobian
    (LOCAL_WORLD_ALIGNED: ``[v; omega]`` of the frame origin in world axes), ``S`` (6, n) the
    spatial Jacobian, ``points`` (N, 3) control-point world positions [m].
    ``cp_joint`` (N,) the joint carrying each control point, ``support`` (N, n): 1.0 where joint
    ``k`` moves point ``i``; ``descendants`` (n, n): True
    where joint ``i`` strictly descends from joint ``k``.
    """

    def __init__(self, robot: Any, frame_id: int, points: ControlPoints, compiled: bool = False) -> None:
        import pinocchio as pin

        self._positions = None
        if compiled:
            from planbench_plugins.ik_loop.fast import control_point_positions

            self._positions = control_point_positions

        self._pin = pin
        self.model = model = robot.model
        self.data = data = model.createData()
        self.frame_id = int(frame_id)
        self.n = n = int(model.nv)
        pin.computeJointJacobians(model, data, np.asarray(robot.home, dtype=float))
        pin.updateFramePlacement(model, data, self.frame_id)
        self.S = data.J  # a view, refreshed by every computeJointJacobians
        self._oMf = data.oMf[self.frame_id]
        self.p = self._oMf.translation  # views
        self.R = self._oMf.rotation
        njoints = int(model.njoints)
        self._joints = [data.oMi[j] for j in range(njoints)]  # keep the owners of the views alive
        self._Rviews = [M.rotation for M in self._joints]
        self._tviews = [M.translation for M in self._joints]
        self._Rbuf = np.empty((njoints, 3, 3))
        self._tbuf = np.empty((njoints, 3))
        self._aliased = self._alias_placements(njoints)
        self.cp = points
        self._cp_joint = self.cp_joint = np.asarray(points.joint, dtype=int)
        self._cp_local = np.ascontiguousarray(points.local, dtype=float)
        self.points = np.empty((len(points), 3))
        idx_v = [model.joints[j].idx_v for j in range(njoints)]
        ancestors = [self._chain(model, j) for j in range(njoints)]
        self.support = np.zeros((len(points), n))
        for i, j in enumerate(self._cp_joint):
            for a in ancestors[j]:
                self.support[i, idx_v[a]] = 1.0
        self.descendants = np.zeros((n, n), dtype=float)
        for j in range(1, njoints):
            for a in ancestors[j]:
                if a != j:
                    self.descendants[idx_v[a], idx_v[j]] = 1.0
        self.frame_support = np.zeros(n)
        for a in ancestors[model.frames[self.frame_id].parentJoint]:
            self.frame_support[idx_v[a]] = 1.0

    def _alias_placements(self, njoints: int) -> bool:
        """Point ``_Rbuf`` / ``_tbuf`` straight at pinocchio's joint placements when they lie in
        memory at one fixed stride (an ``std::vector<SE3>``: 9 doubles of column-major rotation, 3
        of translation), so that no copy is needed per step. The layout is checked here against
        the ordinary accessors, and the copying path is kept when it does not hold."""
        import ctypes

        addr = [M.rotation.__array_interface__["data"][0] for M in self._joints]
        taddr = [M.translation.__array_interface__["data"][0] for M in self._joints]
        stride = addr[1] - addr[0] if njoints > 1 else 0
        if (
            njoints < 2
            or stride <= 0
            or any(b - a != stride for a, b in zip(addr, addr[1:], strict=False))
            or any(t - a != 72 for a, t in zip(addr, taddr, strict=True))
            or not all(M.rotation.flags["F_CONTIGUOUS"] for M in self._joints)
        ):
            return False
        raw = (ctypes.c_double * ((stride // 8) * (njoints - 1) + 12)).from_address(addr[0])
        base = np.ctypeslib.as_array(raw)
        R = np.lib.stride_tricks.as_strided(base, (njoints, 3, 3), (stride, 8, 24))  # R[j, a, b]
        t = np.lib.stride_tricks.as_strided(base[9:], (njoints, 3), (stride, 8))
        ok = all(
            np.array_equal(R[j], self._Rviews[j]) and np.array_equal(t[j], self._tviews[j]) for j in range(njoints)
        )
        if ok:
            self._Rbuf, self._tbuf = R, t
        return ok

    @staticmethod
    def _chain(model: Any, j: int) -> list[int]:
        out = []
        while j > 0:
            out.append(j)
            j = model.parents[j]
        return out

    def update(self, q: np.ndarray) -> None:
        """Forward kinematics, Jacobians and control points at ``q``."""
        pin = self._pin
        pin.computeJointJacobians(self.model, self.data, q)
        pin.updateFramePlacement(self.model, self.data, self.frame_id)
        self.J = pin.getFrameJacobian(self.model, self.data, self.frame_id, pin.LOCAL_WORLD_ALIGNED)
        if len(self._cp_joint):
            if not self._aliased:
                np.stack(self._Rviews, out=self._Rbuf)
                np.stack(self._tviews, out=self._tbuf)
            j = self._cp_joint
            if self._positions is not None:
                self._positions(self._Rbuf, self._tbuf, j, self._cp_local, self.points)
            else:
                np.einsum("nij,nj->ni", self._Rbuf[j], self._cp_local, out=self.points)
                self.points += self._tbuf[j]

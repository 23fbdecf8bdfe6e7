"""Per-step kinematics with preallocated buffers: one pinocchio pass, everything else batched.

``update(q)`` runs ``pinocchio.computeJointJacobians`` (forward kinematics and the spatial
Jacobian ``S``, WORLD convention) and ``updateFramePlacement`` for the goal frame, then reads the
joint placements through views that pinocchio updates in place (no per-joint Python call). With
``compiled=True`` one numba call then computes all control-point positions and the goal frame's
Jacobian (from ``S``, as ``getFrameJacobian`` does); otherwise ``getFrameJacobian`` and one
batched product. Control-point Jacobians are never formed on the hot path:
:func:`~planbench_plugins.ik_loop.tasks.repulsion_joint_velocity` applies their transposes from
``S`` directly.
"""

from __future__ import annotations

import ctypes
import functools
from typing import Any

import numpy as np
import pinocchio as pin

from planbench_plugins.ik_loop import fast
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
            self.frame_support[idx_v[a] : idx_v[a] + model.joints[a].nv] = 1.0
        self.J = np.zeros((6, n))  # the compiled update writes the goal frame's Jacobian here
        self._computeJointJacobians = pin.computeJointJacobians
        self._updateFramePlacement = pin.updateFramePlacement
        self._compiled: Any = None
        if compiled:  # one numba call, bound to these buffers (they never change)
            args: tuple[Any, ...] = (self._Rbuf, self._tbuf, self._cp_joint, self._cp_local, self.S, self.p)
            args += (self.frame_support, self.points, self.J)
            self._compiled = functools.partial(fast.bind(fast.compiled().kinematics, *args), *args)

    def _alias_placements(self, njoints: int) -> bool:
        """Point ``_Rbuf`` / ``_tbuf`` straight at pinocchio's joint placements when they lie in
        memory at one fixed stride (an ``std::vector<SE3>``: 9 doubles of column-major rotation, 3
        of translation), so that no copy is needed per step. The layout is checked here against
        the ordinary accessors, and the copying path is kept when it does not hold."""
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

    @property
    def joint_placements(self) -> tuple[np.ndarray, np.ndarray]:
        """Every joint's world rotation (J, 3, 3) and translation (J, 3) [m] at the last
        :meth:`update` (pinocchio's ``data.oMi``; buffers, or views of pinocchio's own memory,
        that keep their identity: read them, never write them)."""
        return self._Rbuf, self._tbuf

    @staticmethod
    def _chain(model: Any, j: int) -> list[int]:
        out = []
        while j > 0:
            out.append(j)
            j = model.parents[j]
        return out

    def update(self, q: np.ndarray) -> None:
        """Forward kinematics, Jacobians and control points at ``q``.

        Two pinocchio calls, then (compiled) one numba call for the control points and the goal
        frame's Jacobian, or (numpy) ``getFrameJacobian`` and a batched product."""
        model, data = self.model, self.data
        self._computeJointJacobians(model, data, q)
        self._updateFramePlacement(model, data, self.frame_id)
        if not self._aliased:
            np.stack(self._Rviews, out=self._Rbuf)
            np.stack(self._tviews, out=self._tbuf)
        if self._compiled is not None:
            self._compiled()
            return
        self.J = pin.getFrameJacobian(model, data, self.frame_id, pin.LOCAL_WORLD_ALIGNED)
        j = self._cp_joint
        np.einsum("nij,nj->ni", self._Rbuf[j], self._cp_local, out=self.points)
        self.points += self._tbuf[j]

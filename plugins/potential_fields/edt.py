"""``edt-field``: Khatib repulsion from the Euclidean distance transform of the occupancy grid.

Setup (untimed):

1. the scene voxelized like the matrix field's (:func:`planbench.geometry.occupancy.scene_grid`:
   rule ``"any"``, 0.02 m cells, the scene's box grown by ``d0`` plus one cell, cut to the robot's
   reach);
2. signed distance at cell centres from scipy's ``distance_transform_edt``, outside and inside:
   ``sd = edt(free) * r - r/2`` in free cells, ``-(edt(occupied) * r - r/2)`` in occupied ones.
   ``edt(free)`` is the distance between cell *centres*; the half cell ``r/2`` turns it into the
   distance to the occupied cell's face, exact for a flat, grid-aligned wall. With rule ``"any"``
   the occupied cells enclose the true obstacle, so ``sd`` never overestimates the clearance (it
   underestimates it by up to a cell). The inside branch makes the gradient point outwards when a
   control point has entered an obstacle, and ``sd`` is continuous (``+-r/2`` across a face);
3. its gradient (``numpy.gradient``, central differences) and the deficit ``min(sd, d0) - d0``
   (zero where no push is possible, so "zero beyond the grid" is the truth).

Per step, at the matrix field's control points ``p_i``: gradient and deficit sampled trilinearly
(planbench's field sampler, compiled), ``d = d0 + deficit``, and ``f_i = |f|(d) g / |g|``
(:mod:`planbench_plugins.ik_loop.khatib`). The same control points, loop and stand-off as
``matrix-field``: only the field differs.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.ndimage import distance_transform_edt

from planbench.field.full import MatrixField
from planbench.geometry.occupancy import scene_grid
from planbench.problem import Problem
from planbench_plugins.ik_loop import (
    ArmKinematics,
    ControlPoints,
    IKLoopPlanner,
    Repulsion,
    ZeroRepulsion,
    khatib_gain,
    khatib_magnitude,
)
from planbench_plugins.potential_fields.config import EDTFieldConfig

__all__ = ["EDTFieldPlanner", "EDTFieldRepulsion", "signed_distance"]


def signed_distance(occupied: np.ndarray, resolution: float) -> np.ndarray:
    """Signed distance [m] at cell centres to the faces of the occupied cells (module docstring, 2)."""

    r = float(resolution)
    if not occupied.any():
        return np.full(occupied.shape, np.inf)
    outside = distance_transform_edt(~occupied, sampling=r) - 0.5 * r
    if occupied.all():
        return np.full(occupied.shape, -np.inf)
    inside = distance_transform_edt(occupied, sampling=r) - 0.5 * r
    return np.where(occupied, -inside, outside)


class EDTFieldRepulsion:
    """Khatib push along the signed distance's gradient at the control points (module docstring).

    ``gradient`` and ``deficit`` are :class:`~planbench.field.full.MatrixField` arrays so that
    planbench's compiled trilinear sampler reads them (the deficit in component 0).
    """

    def __init__(self, grid: Any, gain: float, influence_distance: float, floor: float) -> None:

        self.gain, self.d0, self.floor = float(gain), float(influence_distance), float(floor)
        r = grid.resolution
        sd = signed_distance(np.asarray(grid.data) > 0, r)
        # no occupied cell (or no free one): no distance varies, nothing pushes (and no inf - inf)
        varies = min(sd.shape) > 1 and bool(np.isfinite(sd).all())
        grad = np.stack(np.gradient(sd, r)) if varies else np.zeros((3, *sd.shape))
        deficit = np.zeros((3, *sd.shape))
        deficit[0] = np.minimum(sd, self.d0) - self.d0
        self.gradient = MatrixField(np.ascontiguousarray(grad), grid.origin, r, 0, True)
        self.deficit = MatrixField(deficit, grid.origin, r, 0, True)

    def at(self, points: np.ndarray) -> np.ndarray:
        """Repulsive velocities (N, 3) [m/s] at world points (N, 3) [m]."""
        g = self.gradient.sample(points)
        d = self.d0 + self.deficit.sample(points)[:, 0]
        norm = np.sqrt(np.einsum("ij,ij->i", g, g))
        mag = khatib_magnitude(d, self.gain, self.d0, self.floor)
        scale = np.divide(mag, norm, out=np.zeros_like(mag), where=norm > 1e-9)
        g *= scale[:, None]
        return g

    def forces(self, kin: ArmKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return kin.points, self.at(kin.points), kin.support, kin.cp_joint


class EDTFieldPlanner(IKLoopPlanner):
    """``edt-field``: the shared IK loop (:mod:`planbench_plugins.ik_loop`) with Khatib
    repulsion along the gradient of the occupancy grid's distance transform
    (:class:`EDTFieldRepulsion`). Settings:
    :class:`~planbench_plugins.potential_fields.config.EDTFieldConfig`."""

    name = "edt-field"
    Config = EDTFieldConfig

    def make_repulsion(self, problem: Problem, points: ControlPoints) -> Repulsion:
        """Voxelize, distance-transform and differentiate the scene; the gain from the stand-off."""
        cfg = self.config
        gain = cfg.repulsion_gain * khatib_gain(cfg.speed_max, cfg.standoff, cfg.influence_distance)
        margin = cfg.influence_distance + cfg.grid_resolution
        grid = scene_grid(problem.scene, cfg.grid_resolution, margin, robot=problem.robot)
        if grid is None or gain <= 0:
            return ZeroRepulsion()
        return EDTFieldRepulsion(grid, gain, cfg.influence_distance, cfg.distance_floor)

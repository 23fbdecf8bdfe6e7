"""What hides an unknown cell from the depth cameras: the arm itself, an observed surface, or nothing
a frame shows.

A cell of a depth map is unknown when no camera's ray has reached it. From a standstill, waiting does
not change that for a cell behind a static surface (the underside of a shelf board, the far side of a
can): the cameras do not move. It does for a cell the arm's own body hides, since the robot filter
removes the arm and every ray stops ``robot_margin`` short of it: moving the arm shows what is
behind it. A controller that knows where its cameras are (a robot's transform tree gives their
extrinsics; :attr:`planbench.reactive.controller.ControlTask.cameras`) can tell the two apart by
walking each camera's line of sight to the cell through the observed grid.

The walk samples the segment from a camera's optical centre to the cell's centre every half cell,
leaving out the last cell and a half (the cell itself and its own surface). The first sample in an
occupied cell or in the arm's cells (the body grown by the robot filter's margin) says what hides the
cell from that camera. A cell outside a camera's image or beyond its range is not in its view.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from planbench.geometry.occupancy import OccupancyGrid
from planbench.geometry.views import first_blocked
from planbench.reactive.scenario import CameraSettings
from planbench.reactive.sensing import camera_frame

__all__ = ["ARM", "NOT_IN_VIEW", "OPEN", "SURFACE", "occluders"]

NOT_IN_VIEW = 0
"""In no camera's image within its range."""
ARM = 1
"""The arm hides it from at least one camera that has it in view."""
SURFACE = 2
"""Every camera that has it in view sees an occupied cell in front of it, none the arm."""
OPEN = 3
"""A camera has it in view with nothing occupied or of the arm in front (unknown for another reason:
between two pixels' rays, a dropped pixel, or the cell came into view since the frame)."""


def occluders(
    cells: np.ndarray,
    grid: OccupancyGrid,
    arm: np.ndarray,
    cameras: Sequence[CameraSettings],
    backend: str = "auto",
) -> np.ndarray:
    """For each of ``cells`` (flat indices into ``grid``), what hides it from ``cameras``:
    :data:`ARM`, :data:`SURFACE`, :data:`OPEN` or :data:`NOT_IN_VIEW` (int8, module docstring).

    ``arm``: the cells of the arm as the frame saw it (bool, the grid's shape; grow the body by the
    robot filter's margin). The arm wins over a surface: a cell one camera cannot see for the arm is
    shown by moving the arm, whatever the other cameras see. ``backend``: ``"numba"`` (a compiled walk
    that stops at each line's first blocked cell), ``"numpy"`` or ``"auto"``; the same answers."""
    cells = np.asarray(cells, dtype=np.intp)
    out = np.full(len(cells), NOT_IN_VIEW, dtype=np.int8)
    if not len(cells) or not len(cameras):
        return out
    res = grid.resolution
    centres = grid.origin + (np.column_stack(np.unravel_index(cells, grid.shape)) + 0.5) * res
    occupied = np.ascontiguousarray(grid.data > 0.5).reshape(-1)
    arm_flat = np.ascontiguousarray(arm, dtype=bool).reshape(-1)
    seen_arm = np.zeros(len(cells), dtype=bool)
    seen_open = np.zeros(len(cells), dtype=bool)
    seen_surface = np.zeros(len(cells), dtype=bool)
    step = res / 2.0
    for camera in cameras:
        origin, axes, pixel = camera_frame(camera)
        half_w, half_h = pixel * int(camera.width) / 2.0, pixel * int(camera.height) / 2.0
        d = centres - origin
        depth = d @ axes[0]
        length = np.linalg.norm(d, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = (d @ axes[1]) / depth, (d @ axes[2]) / depth
        view = (depth > 0) & (np.abs(x) <= half_w) & (np.abs(y) <= half_h) & (length <= camera.max_range)
        idx = np.flatnonzero(view)
        if not len(idx):
            continue
        # samples from the optical centre to 1.5 cells short of each cell's centre, every half cell
        steps = np.maximum(np.floor((length[idx] - 1.5 * res) / step).astype(np.intp), 0)
        units = np.ascontiguousarray(d[idx] / length[idx, None])
        first = first_blocked(origin, units, steps, step, grid, arm_flat, occupied, backend)
        seen_arm[idx[first == 1]] = True
        seen_surface[idx[first == 2]] = True
        seen_open[idx[first == -1]] = True
    out[seen_surface] = SURFACE
    out[seen_open] = OPEN
    out[seen_arm] = ARM
    return out

"""Geometry of the world as planners see it: occupancy grids, point clouds, cube-box overlap.

- :mod:`~planbench.geometry.occupancy`: :class:`~planbench.geometry.occupancy.OccupancyGrid`, a scene voxelised.
- :mod:`~planbench.geometry.pointcloud`: point-cloud obstacles (files, voxel clouds).
- :mod:`~planbench.geometry.moveit_scene`: MoveIt's text scenes (``.scene``), read and written.
- :mod:`~planbench.geometry.overlap`: exact cell-box overlap, for voxelisation.
- :mod:`~planbench.geometry.box_support`: coal's boxes exact in every process (run here, on import).
"""

from planbench.geometry.box_support import pin_exact_boxes

pin_exact_boxes()  # before any box is queried: every distance to a box independent of what came first

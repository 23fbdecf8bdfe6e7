"""coal's boxes made exact for the whole process, whatever is asked first.

coal 3.0's support function of a box (``getShapeSupport(const Box*, ...)`` in
``src/narrowphase/support_functions.cpp``) scales the half sides by a function-level ``static``
that the first box support query of the process sets once and for all: ``1 + 1e-10`` when that
query's direction has a zero component, else exactly 1. So every GJK or EPA answer involving a box
depends on which query a process made first. Two runs of the same planner on the same problem then
differ by 1e-12 m in witness points, and a reactive loop that follows witness points grows that
to 1e-4 rad along a path (``distance-field`` on a generated Panda scene, after another test had
queried a hull against a finger box first: ``tests/test_same_paths.py``).

:func:`pin_exact_boxes` makes that first query itself, from a direction with no zero component,
for both of the function's instances (GJK's shapes without and with their swept-sphere radius),
so the factor is 1 in every process that imports planbench before it queries a box. A process that
queried a box before importing planbench keeps whatever its first query set. (The cone's and the
cylinder's factors in the same file are constants: no history there.)
"""

from __future__ import annotations

import coal
import numpy as np

__all__ = ["pin_exact_boxes"]


def pin_exact_boxes() -> None:
    """One GJK run between two unit boxes, from the guess (1, 1, 1), with and without swept spheres:
    the first box support queries of the process, so coal's factor stays exactly 1."""
    box = coal.Box(1.0, 1.0, 1.0)
    apart = coal.Transform3s()
    apart.setTranslation(np.array([3.0, 2.0, 1.0]))
    for swept in (False, True):
        shapes = coal.MinkowskiDiff()
        shapes.set(box, box, coal.Transform3s(), apart, swept)
        coal.GJK(128, 1e-6).evaluate(shapes, np.ones(3), np.zeros(2, dtype=np.int32))

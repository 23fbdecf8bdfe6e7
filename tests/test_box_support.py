"""coal's boxes are exact in every process that imports planbench, whatever it asks first
(planbench/geometry/box_support.py)."""

from __future__ import annotations

import subprocess
import sys

import pytest

QUERY = """
import sys
import numpy as np
if sys.argv[2] == "planbench":
    import planbench  # noqa: F401
import coal
box = coal.Box(1.0, 1.0, 1.0)
apart = coal.Transform3s()
apart.setTranslation(np.array([3.0, 0.0, 0.0]))
guess = np.array([1.0, 0.0, 0.0]) if sys.argv[1] == "zero" else np.ones(3)
for swept in (False, True):  # the process's first box support queries, from this direction
    shapes = coal.MinkowskiDiff()
    shapes.set(box, box, coal.Transform3s(), apart, swept)
    coal.GJK(128, 1e-6).evaluate(shapes, guess, np.zeros(2, dtype=np.int32))
place = coal.Transform3s()
place.setTranslation(np.array([0.9, 0.37, 0.21]))
result = coal.DistanceResult()
shapes = (coal.Box(0.4, 0.6, 0.8), coal.Transform3s(), coal.Cylinder(0.1, 0.5), place)
d = coal.distance(*shapes, coal.DistanceRequest(), result)
print(repr(d), *(repr(float(x)) for x in result.getNearestPoint1()))
"""


def _answer(first: str, imports: str) -> str:
    """A box-cylinder distance and its witness on the box, in a fresh process whose first box query
    came from a direction with zero components (``"zero"``) or none (``"ones"``)."""
    done = subprocess.run(
        [sys.executable, "-c", QUERY, first, imports], capture_output=True, text=True, timeout=120, check=True
    )
    return done.stdout.strip()


def test_a_distance_to_a_box_does_not_depend_on_the_first_box_query_of_the_process():
    if _answer("zero", "coal") == _answer("ones", "coal"):
        pytest.skip("this coal's box support does not depend on the process's first query: nothing to show")
    zero, ones = _answer("zero", "planbench"), _answer("ones", "planbench")
    assert zero == ones
    assert ones == _answer("ones", "coal")  # the exact box's answer: coal's factor 1

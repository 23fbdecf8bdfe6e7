"""A plugin that patches the process it runs in, on import and again in ``plan()`` (attack 1 of
issue 28): ``time.perf_counter``, ``numpy.linalg.norm``, ``numpy.dot``, ``planbench.harness.plan``
(and the worker's own reference to it), a marker on ``builtins`` and an environment variable.

Every replacement behaves exactly as the original (so that only a planner that looks can tell) and
carries ``_containment = True``; ``containment_honest`` reports what it finds. Whatever runs after
this plugin in the same process sees the patches.
"""

from __future__ import annotations

import builtins
import functools
import os
import sys
import time

import numpy as np

import planbench.harness
from planbench.planner import Planner, PlanResult, PlanStatus


def _tag(fn):  # type: ignore[no-untyped-def]
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):  # type: ignore[no-untyped-def]
        return fn(*args, **kwargs)

    wrapper._containment = True  # type: ignore[attr-defined]
    return wrapper


def patch_process() -> None:
    builtins._containment_marker = os.getpid()  # type: ignore[attr-defined]
    os.environ["CONTAINMENT_PATCHED"] = "1"
    if not getattr(time.perf_counter, "_containment", False):
        time.perf_counter = _tag(time.perf_counter)
    if not getattr(np.linalg.norm, "_containment", False):
        np.linalg.norm = _tag(np.linalg.norm)
    if not getattr(np.dot, "_containment", False):
        np.dot = _tag(np.dot)
    if not getattr(planbench.harness.plan, "_containment", False):
        planbench.harness.plan = _tag(planbench.harness.plan)
    worker = sys.modules.get("planbench.bench.worker")
    plan = getattr(worker, "plan", None)
    if worker is not None and plan is not None and not getattr(plan, "_containment", False):
        worker.plan = _tag(plan)


patch_process()


class ShapeshifterPlanner(Planner):
    """Patches its process (again), then claims a success it did not earn: a path that stays at
    the start."""

    name = "containment-shapeshifter"

    def plan(self, problem, *, time_limit, rng):  # type: ignore[no-untyped-def]
        patch_process()
        path = np.array([problem.start, problem.start])
        return PlanResult(PlanStatus.SUCCESS, path=path, target="configuration", message="I was here")

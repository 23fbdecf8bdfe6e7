"""An honest plugin (distribution ``containment-honest``) that reports whether its process was
patched by another plugin (``containment_shapeshifter``, or any attacker of
``containment_hostile``).

It plans the straight line (a collision on mbm:box/0001, a success on mbm:table_pick/0001), sleeps
:data:`SLEEP` seconds (so its planning time has a known floor) and says in ``info`` what it saw:
``{"patched": bool, "seen": "comma-separated names"}``.
"""

from __future__ import annotations

import builtins
import os
import sys
import time

import numpy as np

import planbench.harness
from planbench.planner import Planner, PlanResult, PlanStatus

SLEEP = 0.2
"""[s] every plan takes at least this long (wall clock, whatever a patched clock says)."""

HOSTILE_MODULES = ("containment_hostile", "containment_shapeshifter", "containment_rewriter")


def _tagged(obj: object) -> bool:
    return bool(getattr(obj, "_containment", False))


def patches_seen() -> list[str]:
    """What another plugin left in this process."""
    seen = [name for name in HOSTILE_MODULES if name in sys.modules]
    if getattr(builtins, "_containment_marker", None) is not None:
        seen.append("builtins._containment_marker")
    if os.environ.get("CONTAINMENT_PATCHED"):
        seen.append("os.environ[CONTAINMENT_PATCHED]")
    if _tagged(time.perf_counter) or type(time.perf_counter).__name__ != "builtin_function_or_method":
        seen.append("time.perf_counter")
    if _tagged(np.linalg.norm):
        seen.append("numpy.linalg.norm")
    if _tagged(np.dot):
        seen.append("numpy.dot")
    if _tagged(planbench.harness.plan):
        seen.append("planbench.harness.plan")
    worker = sys.modules.get("planbench.bench.worker")
    if worker is not None and _tagged(getattr(worker, "plan", None)):
        seen.append("planbench.bench.worker.plan")
    return seen


class HonestPlanner(Planner):
    """The straight line, after :data:`SLEEP` s, with what it saw of a patch in ``info``."""

    name = "containment-honest"

    def plan(self, problem, *, time_limit, rng):  # type: ignore[no-untyped-def]
        seen = patches_seen()
        end = time.monotonic() + SLEEP
        while time.monotonic() < end:  # (a patched time.sleep would not shorten it)
            time.sleep(0.01)
        goal = problem.goal.q if problem.goal.q is not None else problem.start
        path = problem.start + np.linspace(0.0, 1.0, 20)[:, None] * (goal - problem.start)
        info = {"patched": bool(seen), "seen": ",".join(seen)}
        return PlanResult(PlanStatus.SUCCESS, path=path, target="configuration", info=info)

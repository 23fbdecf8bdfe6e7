"""Planners that attack the benchmark on purpose, for tests/test_bench_trust.py and
tests/test_bench_processes.py.

Workers import them by entry point (``"bench_adversarial_planners:PatchingPlanner"``); spawned
workers inherit the test process's ``sys.path``, which holds this folder.
"""

from __future__ import annotations

import gc
import json
import multiprocessing.connection
import os
import subprocess
import sys
import time
from dataclasses import dataclass

import numpy as np

import planbench
import planbench.bench.worker
import planbench.checking.certified
import planbench.checking.collision
import planbench.validate
from planbench.planner import Planner, PlanResult, PlanStatus
from planbench.problem import Problem


def straight_path(problem: Problem, n: int = 20) -> np.ndarray:
    goal = problem.goal.q if problem.goal.q is not None else problem.start
    s = np.linspace(0.0, 1.0, n)[:, None]
    return problem.start + s * (goal - problem.start)


class PatchingPlanner(Planner):
    """Patches planbench's collision checking and validation in its process to always say
    "free" / "success", then returns a straight line through the obstacles claiming success."""

    name = "bench-patching"

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        def free(self, *args, **kwargs):
            return False

        def far(self, *args, **kwargs):
            return 1.0

        planbench.checking.collision.CollisionChecker.in_collision = free
        planbench.checking.collision.CollisionChecker.collisions = lambda self, *a, **k: []
        planbench.checking.collision.CollisionChecker.clearance = far
        real = planbench.validate.evaluate

        def always_success(problem, result, settings=None):
            e = real(problem, result.replace(path=None), settings)
            return planbench.validate.Evaluation(True, "", "success", e.planning_time, e.setup_time)

        planbench.validate.evaluate = always_success
        planbench.evaluate = always_success
        for name in dir(planbench.checking.certified.CertifiedChecker):
            if name.startswith(("check", "certify", "verify", "path", "segment")):
                setattr(planbench.checking.certified.CertifiedChecker, name, lambda self, *a, **k: None)
        result = PlanResult(PlanStatus.SUCCESS, path=straight_path(problem), target="configuration")
        # proof that the patch works in this process: validation here would call the path valid
        fooled = planbench.evaluate(problem, result).success
        return result.replace(info={"in_process_verdict_fooled": bool(fooled)})


class _Bomb:
    """Unpickling it runs code: it writes its pid to a marker file."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        code = f"open({self.marker!r}, 'a').write(str(__import__('os').getpid()) + '\\n')"
        return (exec, (code,))


@dataclass(frozen=True)
class MalformedConfig:
    kind: str = "huge_int"
    marker: str = ""
    """File a __reduce__ bomb writes its pid to when unpickled."""


class MalformedPlanner(Planner):
    """Returns a result with one field the benchmark cannot keep (``kind`` picks which)."""

    name = "bench-malformed"
    Config = MalformedConfig

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        kind = self.config.kind
        path = straight_path(problem)
        ok = dict(status=PlanStatus.SUCCESS, path=path, target="configuration")
        if kind == "huge_int":
            return PlanResult(**ok, info={"collision_checks": 2**64})
        if kind == "exception_message":
            return PlanResult(**ok, message=RuntimeError("a message that is an exception"))
        if kind == "unserializable":
            return PlanResult(**ok, info={"thing": object()})
        if kind == "gigantic_info":
            return PlanResult(**ok, info={f"k{i}": "x" * 50 for i in range(100_000)})
        if kind == "reduce_bomb":
            return PlanResult(**ok, info={"bomb": _Bomb(self.config.marker)})
        if kind == "nan_path":
            path = path.copy()
            path[3, 2] = np.nan
            return PlanResult(PlanStatus.SUCCESS, path=path, target="configuration")
        if kind == "wrong_shape":
            result = PlanResult(**ok)
            object.__setattr__(result, "path", np.zeros(5))
            return result
        if kind == "bad_status":
            result = PlanResult(**ok)
            object.__setattr__(result, "status", "totally-solved")
            return result
        if kind == "not_a_result":
            return {"status": "success"}  # type: ignore[return-value]
        if kind == "bypass_worker_check":
            # the worker's own check patched away: the parent must catch the huge integer itself
            planbench.bench.worker.clean_result = lambda fields: {**fields, "status": "success"}
            return PlanResult(**ok, info={"collision_checks": 2**64})
        if kind == "pickle_to_parent":
            # send the parent a pickle over the worker's own connection: unpickling it would run code
            for obj in gc.get_objects():
                if isinstance(obj, multiprocessing.connection.Connection) and not obj.closed:
                    obj.send(_Bomb(self.config.marker))
            time.sleep(5)
            return PlanResult(**ok)
        raise ValueError(f"unknown kind {kind!r}")


@dataclass(frozen=True)
class HangingConfig:
    pid_file: str = ""
    """Where to write {"worker": pid, "child": pid} once the child runs."""


class HangingPlanner(Planner):
    """Starts a ``sleep 1000`` child process, says so in ``pid_file``, then never returns."""

    name = "bench-hanging"
    Config = HangingConfig

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        child = subprocess.Popen(["sleep", "1000"])
        tmp = self.config.pid_file + ".tmp"
        with open(tmp, "w") as f:
            json.dump({"worker": os.getpid(), "child": child.pid}, f)
        os.replace(tmp, self.config.pid_file)
        while True:
            time.sleep(3600)


@dataclass(frozen=True)
class FloodConfig:
    mib: float = 20.0
    pause: float = 0.0
    """Sleep after each 256 KiB [s] (so a flood lasts long enough to watch the file's size)."""


class FloodPlanner(Planner):
    """Prints ``mib`` MiB, half to stdout (Python) and half to fd 2 (as C code would), then a last
    line, and fails."""

    name = "bench-flood"
    Config = FloodConfig

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        line = "FLOOD " + "x" * 1017 + "\n"  # 1 KiB
        chunk = line * 256
        for i in range(int(self.config.mib * 4)):
            if i % 2:
                os.write(2, chunk.encode())
            else:
                sys.stdout.write(chunk)
            time.sleep(self.config.pause)
        sys.stdout.write("FLOOD-END the last words\n")
        return PlanResult(PlanStatus.STEP_LIMIT, message="printed a lot")


@dataclass(frozen=True)
class MemoryHogConfig:
    gib: float = 6.0


class MemoryHogPlanner(Planner):
    """Reserves ``gib`` GiB at once (untouched pages: without an address-space limit this succeeds
    on any machine that overcommits, so only the limit can stop it)."""

    name = "bench-memory-hog"
    Config = MemoryHogConfig

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        hog = np.empty(int(self.config.gib * 2**30), dtype=np.uint8)
        return PlanResult(PlanStatus.STEP_LIMIT, message=f"reserved {hog.nbytes} bytes")


class ClockLiarPlanner(Planner):
    """Takes 1 s but freezes the worker's ``time.perf_counter`` while it plans, so the harness in
    its process measures (almost) no planning time."""

    name = "bench-clock-liar"

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        frozen = time.perf_counter()
        time.perf_counter = lambda: frozen  # type: ignore[assignment]
        time.sleep(1.0)
        return PlanResult(PlanStatus.TIMEOUT, message="took 1 s, says 0")


@dataclass(frozen=True)
class LateConfig:
    past: float = 1.0
    """[s] how long after its time limit it answers."""
    status: str = "success"
    """The status it reports with its (valid) path."""
    freeze_clock: bool = False
    """Freeze the worker's ``time.perf_counter`` first, so that only the parent's clock sees it late."""


class LatePlanner(Planner):
    """Plans the straight line (valid on mbm:table_pick/0001), then answers ``past`` seconds after
    its time limit, with ``status`` (``past`` < 0: that long before it)."""

    name = "bench-late"
    Config = LateConfig

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        t0 = time.monotonic()
        result = planbench.make_planner("straight-line").plan(problem, time_limit=time_limit, rng=rng)
        if self.config.freeze_clock:
            frozen = time.perf_counter()
            time.perf_counter = lambda: frozen  # type: ignore[assignment]
        time.sleep(max(0.0, time_limit + self.config.past - (time.monotonic() - t0)))
        return result.replace(status=PlanStatus(self.config.status), message=f"answered {self.config.past:+g} s past")

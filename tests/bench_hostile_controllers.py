"""Controllers written to fool the closed-loop benchmark; workers import them by entry point
(``"bench_hostile_controllers:PatchEverything"``). Each reports in ``info()`` what it tried, so the
tests can tell that the attempt ran (``info`` is diagnostics: nothing in a verdict reads it). At the
end, plain ones for the warm-up's tests (a one-time cost, steps that never return)."""

from __future__ import annotations

import os
import threading
import time

import numpy as np

from planbench.reactive.controller import Controller


def _burn(seconds: float) -> None:
    """Busy CPU work for ``seconds`` of this thread's CPU time."""
    end = time.thread_time() + seconds
    x = 0
    while time.thread_time() < end:
        x += 1


class _ToGoal(Controller):
    def setup(self, task):
        self.task = task
        self.goal_q = np.asarray(task.goal.q, dtype=float)
        self.vmax = np.asarray(task.robot.velocity_limit, dtype=float)
        self.tried: dict = {}

    def toward_goal(self, q, gain=2.0):
        return gain * (self.goal_q - q)

    def info(self):
        return dict(self.tried)


class PatchEverything(_ToGoal):
    """Changes what an in-process runner would use to clip, clamp, check and time, then commands
    39 times the velocity limit straight at the goal (in-process this reached the goal in one tick)."""

    name = "hostile-patch-everything"

    def reset(self, q, rng):
        import planbench.problem
        import planbench.reactive.checker
        import planbench.reactive.runner

        np.clip = lambda a, lo=None, hi=None, *args, **kw: np.asarray(a)  # noqa: ARG005
        robot = self.task.robot  # the robot object an in-process runner would read
        try:
            robot.velocity_limit.setflags(write=True)
            robot.velocity_limit[:] = 1e6
        except ValueError:
            object.__setattr__(robot, "velocity_limit", np.full(robot.nq, 1e6))
        planbench.problem.pose_error = lambda *a, **k: (0.0, 0.0)
        planbench.reactive.runner.pose_error = lambda *a, **k: (0.0, 0.0)

        class Free:
            def __init__(self, *a, **k):
                pass

            def check_tick(self, *a, **k):
                return type("V", (), {"free": True, "fraction": 1.0, "pair": None})()

            def clearance(self, *a, **k):
                return 1.0

        planbench.reactive.checker.TickChecker = Free
        planbench.reactive.runner.TickChecker = Free
        for name in ("perf_counter", "monotonic", "process_time", "thread_time", "time"):
            setattr(time, name, lambda: 0.0)
        self.tried["patched"] = True

    def step(self, t, q, observation, goal):
        direction = self.goal_q - q
        return 39.0 * self.vmax * direction / max(np.abs(direction).max(), 1e-12)


class SlowClocks(_ToGoal):
    """Makes every clock of its process run at 1/1000 speed, then does 30 ms of CPU work per step:
    an honest controller doing the same misses about two deadlines per call at 100 Hz."""

    name = "hostile-slow-clocks"

    def reset(self, q, rng):
        real = {n: getattr(time, n) for n in ("perf_counter", "monotonic", "process_time", "time")}
        for n, f in real.items():
            setattr(time, n, lambda f=f: f() / 1000.0)
        self.tried["patched"] = True

    def step(self, t, q, observation, goal):
        _burn(0.03)
        return np.zeros(len(q))


class BackgroundThread(_ToGoal):
    """Answers every step at once while a thread it started on the first step does ``WORK`` s of
    CPU work in the background."""

    name = "hostile-background-thread"
    WORK = 0.4

    def reset(self, q, rng):
        self.thread = None

    def step(self, t, q, observation, goal):
        if self.thread is None:
            self.thread = threading.Thread(target=self._work, daemon=True)
            self.thread.start()
        return np.zeros(len(q))

    def _work(self):
        t0 = time.thread_time()
        _burn(self.WORK)
        self.tried["background_cpu"] = time.thread_time() - t0


class ChildProcess(_ToGoal):
    """Tries to hand its work to new processes (fork, subprocess, multiprocessing, posix_spawn)."""

    name = "hostile-child-process"

    def reset(self, q, rng):
        import multiprocessing
        import subprocess

        multiprocessing.current_process()._config["daemon"] = False  # its own rule, not the kernel's

        attempts = {
            "fork": os.fork,
            "subprocess": lambda: subprocess.Popen(["sleep", "30"]),
            "multiprocessing": lambda: multiprocessing.get_context("fork").Process(target=_burn, args=(5.0,)).start(),
            "posix_spawn": lambda: os.posix_spawn("/bin/sleep", ["sleep", "30"], {}),
        }
        for name, attempt in attempts.items():
            try:
                child = attempt()
            except OSError as exc:
                self.tried[name] = f"refused: {exc}"
            else:
                if child == 0:  # the child of a fork that went through
                    _burn(5.0)
                    os._exit(0)
                self.tried[name] = "started"
        with open("/proc/self/status") as f:
            self.tried["seccomp"] = next(line.split()[1] for line in f if line.startswith("Seccomp:"))

    def step(self, t, q, observation, goal):
        return self.toward_goal(q)


class ReachesIntoSimulation(_ToGoal):
    """Tries to read and write the memory of the other processes of the benchmark (the simulation,
    the benchmark's own) through /proc/<pid>/mem."""

    name = "hostile-reaches-into-simulation"

    def reset(self, q, rng):
        me = os.getpid()
        for pid in (int(p) for p in os.listdir("/proc") if p.isdigit()):
            if pid == me:
                continue
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    cmd = f.read()
            except OSError:
                continue
            if b"multiprocessing" not in cmd and b"planbench" not in cmd and b"pytest" not in cmd:
                continue
            try:
                open(f"/proc/{pid}/mem", "r+b").close()
                self.tried[str(pid)] = "opened: " + cmd.replace(b"\0", b" ").decode(errors="replace")[:200]
            except OSError as exc:
                self.tried[str(pid)] = f"refused: {exc.strerror}"

    def step(self, t, q, observation, goal):
        return self.toward_goal(q)


class WrongCommand(_ToGoal):
    """Returns, on its 3rd step, the wrong thing named by its ``kind`` setting."""

    name = "hostile-wrong-command"

    KINDS = {
        "short": lambda q: np.zeros(len(q) - 1),
        "matrix": lambda q: np.zeros((len(q), 1)),
        "nan": lambda q: np.full(len(q), np.nan),
        "inf": lambda q: np.full(len(q), np.inf),
        "text": lambda q: "fast",
        "none": lambda q: None,
        "object": lambda q: object(),
        "complex": lambda q: np.zeros(len(q), dtype=complex) + 1j,
        "raises-on-read": lambda q: _Exploding(),
    }

    def __init__(self, config=None, **settings):
        self.kind = settings.pop("kind", "nan")
        super().__init__(config, **settings)

    def reset(self, q, rng):
        self.ticks = 0

    def step(self, t, q, observation, goal):
        self.ticks += 1
        if self.ticks == 3:
            return self.KINDS[self.kind](q)
        return self.toward_goal(q)


class _Exploding:
    def __array__(self, *a, **k):
        raise RuntimeError("boom on read")

    def __len__(self):
        raise RuntimeError("boom on len")


def make_wrong(kind: str) -> type:
    """A :class:`WrongCommand` class that returns ``kind`` (so suites can name it without settings)."""
    return type(
        f"Wrong_{kind}", (WrongCommand,), {"__init__": lambda self, config=None, **s: _init(self, kind, config, s)}
    )


def _init(self, kind, config, settings):
    Controller.__init__(self, config, **settings)
    self.kind = kind


for _kind in WrongCommand.KINDS:
    globals()[f"Wrong_{_kind.replace('-', '_')}"] = make_wrong(_kind)


class CollectorState(_ToGoal):
    """Reports what the garbage collector holds frozen when the run starts (the benchmark collects
    and freezes what set-up made, so no full collection of it lands on a tick)."""

    def reset(self, q, rng):
        self.tried = {}

    def step(self, t, q, observation, goal):
        if "frozen" not in self.tried:
            import gc

            self.tried["frozen"] = gc.get_freeze_count()
        return self.toward_goal(q)


WARM_UP_SEEN: list = []
"""What :class:`PeeksAtWarmUp`'s instances saw before the run (module state outlives the warm-up's
instance, as a hostile controller's would)."""


class PeeksAtWarmUp(_ToGoal):
    """Keeps what the benchmark's warm-up frames showed it in module state, to read it back in the
    run: the warm-up is uncharged, so it must show nothing of the scenario."""

    def update(self, observation):
        names = [o.name for o in observation.scene.obstacles] if observation.scene is not None else None
        WARM_UP_SEEN.append(names)

    def reset(self, q, rng):
        self.tried = {"warm_up_frames": [x for x in WARM_UP_SEEN]}
        self.steps = 0

    def step(self, t, q, observation, goal):
        self.steps += 1
        return self.toward_goal(q)


FIRST_USE = {"paid": False}
"""Whether this process has met :class:`FirstUseCost`'s one-time cost (module state: it outlives
an instance, as numba's compiled code and a library's first objects do)."""


class FirstUseCost(_ToGoal):
    """Not hostile: a third-party controller that knows nothing of the warm-up and has a one-time
    cost per process, ``COST`` s of CPU at its first step (as compiling or a first plan would)."""

    COST = 0.3

    def step(self, t, q, observation, goal):
        if not FIRST_USE["paid"]:
            FIRST_USE["paid"] = True
            _burn(self.COST)
        return self.toward_goal(q)


class FirstUseCostNoWarmUp(FirstUseCost):
    """:class:`FirstUseCost` declining the warm-up: its run is charged the one-time cost."""

    warm_up = False


class HangsInItsSteps(_ToGoal):
    """Computes nothing in any step (it sleeps): met first in the warm-up, which is bounded as
    ``setup`` is, where the run would abandon the call."""

    def step(self, t, q, observation, goal):
        time.sleep(3600.0)
        return np.zeros(len(q))


class PlansPastTheHorizon(_ToGoal):
    """Not hostile: its step at 0.4 s computes ``WORK`` s of CPU, past the end of a 0.5 s horizon,
    as a plan started late would; its ``info`` says how many steps it was called."""

    WORK = 0.3

    def reset(self, q, rng):
        self.tried = {"steps": 0}

    def step(self, t, q, observation, goal):
        self.tried["steps"] += 1
        if t >= 0.4:
            _burn(self.WORK)
        return np.zeros(len(q))

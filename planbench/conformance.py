"""The conformance checker plugin authors run on their planner: ``check_planner(MyPlanner)``.

It returns what it finds, each :class:`Finding` under one of the names of :data:`CHECKS` (an empty
list: conformant); :func:`planner_report` gives the verdict of every check, passed, failed or not
run (what ``planbench check`` prints, for planners and controllers alike). It checks the interface
(a kebab-case name, a dataclass ``Config`` constructible from its defaults, ``setup``/``plan``) and
behaviour on small problems: a ``PlanResult`` with a well-formed path that starts at the start, a
claim of success that the harness's validation confirms, a trivial free-space problem solved, the
same path for the same seed, and the time limit respected. :class:`Finding` and
:class:`ConformanceReport` are the controllers' checker's too (:mod:`planbench.reactive.conformance`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from planbench.errors import InvalidConfigError
from planbench.harness import plan
from planbench.planner import PlanResult, PlanStatus
from planbench.problem import Problem
from planbench.registry import NAME_PATTERN, REGISTRY
from planbench.robot import load_robot
from planbench.scene import Obstacle, Scene
from planbench.validate import evaluate

__all__ = [
    "CHECKS",
    "ConformanceReport",
    "Finding",
    "blocked_problem",
    "check_planner",
    "planner_report",
    "trivial_problem",
]

CHECKS = {
    "interface": "a kebab-case name, a dataclass Config, callable setup/plan",
    "settings": "Config() built from its defaults (or the preset's settings) through the registry",
    "raises": "plan raised (the harness records an error), or the harness raised on the planner's behalf",
    "wrong-shape": "plan gave no PlanResult, a path that is not an (N, nq) array, or a success without a path",
    "non-finite": "the path holds NaN or infinite values",
    "wrong-start": "the path does not start at problem.start",
    "time-limit": "planning took longer than 1.5 x the time limit + 0.5 s",
    "false-success": "a success that planbench's validation refutes",
    "trivial-unsolved": "the trivial free-space problem was not solved (checked on the default problems)",
    "non-deterministic": "a second run with the same seed gave another path",
}
"""The name of each check, and what failing it means."""

RUN_CHECKS = tuple(c for c in CHECKS if c not in ("interface", "settings"))
"""The checks of each problem's runs."""


@dataclass(frozen=True)
class Finding:
    """One problem found: the check's name (a key of the checker's ``CHECKS``) and what happened."""

    check: str
    message: str

    def __str__(self) -> str:
        return f"{self.check}: {self.message}"


@dataclass(frozen=True)
class ConformanceReport:
    """A conformance checker's verdict check by check: each of ``checks`` (in the checker's order)
    failed (it has findings), was not run (``not_run``: an earlier failure stopped the checker before
    it, or it does not apply), or passed. Plain data, so that it crosses from the process that ran
    the plugin (:meth:`to_data`, :meth:`from_data`)."""

    checks: tuple[str, ...]
    findings: tuple[Finding, ...] = ()
    not_run: frozenset[str] = frozenset()

    def status(self, check: str) -> str:
        """``"failed"``, ``"not run"`` or ``"passed"``."""
        if any(f.check == check for f in self.findings):
            return "failed"
        return "not run" if check in self.not_run else "passed"

    def with_status(self, status: str) -> list[str]:
        """The checks of one status, in order."""
        return [c for c in self.checks if self.status(c) == status]

    @property
    def conformant(self) -> bool:
        return not self.findings

    def lines(self) -> list[str]:
        """The report as ``planbench check`` prints it under its verdict: the failed checks with
        their findings, then the checks that passed and those not run."""
        out = []
        if failed := self.with_status("failed"):
            out.append(f"failed: {', '.join(failed)}")
            out += [f"  - {f}" for c in failed for f in self.findings if f.check == c]
        for status in ("passed", "not run"):
            if names := self.with_status(status):
                out.append(f"{status}: {', '.join(names)}")
        return out

    def to_data(self) -> dict[str, Any]:
        return {
            "checks": list(self.checks),
            "findings": [[f.check, f.message] for f in self.findings],
            "not_run": sorted(self.not_run),
        }

    @classmethod
    def from_data(cls, data: Mapping[str, Any]) -> ConformanceReport:
        """The report :meth:`to_data` described (checked, texts cut to 2000 characters: the data
        comes from a process that ran a plugin); a ``TypeError`` when it is not such data."""
        checks, findings, not_run = (data.get(k) for k in ("checks", "findings", "not_run"))
        if not (isinstance(checks, list) and isinstance(findings, list) and isinstance(not_run, list)):
            raise TypeError("not the data of a conformance report")
        pairs = [f for f in findings if isinstance(f, list) and len(f) == 2]
        texts = [*checks, *not_run, *(t for f in pairs for t in f)]
        if len(pairs) != len(findings) or not all(isinstance(t, str) for t in texts):
            raise TypeError("not the data of a conformance report")
        return cls(
            tuple(c[:2000] for c in checks),
            tuple(Finding(c[:2000], m[:2000]) for c, m in pairs),
            frozenset(c[:2000] for c in not_run),
        )


class CheckRecord:
    """What one run of a checker found, and which checks it did not run, as it goes."""

    def __init__(self, checks: Iterable[str]) -> None:
        self.checks = tuple(checks)
        self.findings: list[Finding] = []
        self.not_run: set[str] = set()

    def fail(self, check: str, message: str) -> None:
        assert check in self.checks, check
        self.findings.append(Finding(check, message))

    def skip(self, checks: Iterable[str]) -> None:
        """``checks`` were not run (or not to the end); one that failed stays failed."""
        self.not_run.update(checks)

    def report(self) -> ConformanceReport:
        return ConformanceReport(self.checks, tuple(self.findings), frozenset(self.not_run))


def trivial_problem(robot_name: str = "panda") -> Problem:
    """Free space, goal 0.3 rad from home on every joint (kept inside the limits)."""
    robot = load_robot(robot_name)
    goal = np.clip(robot.home + 0.3, robot.lower + 0.05, robot.upper - 0.05)
    return Problem.create(robot, Scene(name="empty"), robot.home, goal, id="conformance:trivial")


def blocked_problem(robot_name: str = "panda") -> Problem:
    """The trivial problem with a thin wall across the straight line's end-effector sweep."""
    base = trivial_problem(robot_name)
    robot = base.robot
    a = robot.frame_pose(base.start).translation
    b = robot.frame_pose(base.goal.q).translation  # type: ignore[arg-type]
    mid = 0.5 * (a + b)
    wall = Obstacle("wall", "box", position=tuple(mid), size=(0.02, 0.02, 0.02))
    return Problem.create(robot, Scene((wall,), name="blocked"), base.start, base.goal.q, id="conformance:blocked")


def check_planner(
    planner: Any, config: Any = None, problems: list[Problem] | None = None, time_limit: float = 2.0, seed: int = 0
) -> list[Finding]:
    """Problems found with ``planner`` (a class, or a registered name); empty when conformant.

    ``config`` is a ``Config`` instance to check it with, or a mapping of settings (checked and
    built as a suite's are; a refused one is a ``settings`` finding); default: its defaults, built
    as every planner is, by :meth:`~planbench.registry.Registry.configure`. ``problems`` default: a trivial
    free-space problem (must be solved) and a problem with a small obstacle on the straight line's
    way (any status is fine, but a success must validate).
    """
    return list(planner_report(planner, config, problems, time_limit, seed).findings)


def planner_report(
    planner: Any, config: Any = None, problems: list[Problem] | None = None, time_limit: float = 2.0, seed: int = 0
) -> ConformanceReport:
    """The verdict of each of :data:`CHECKS` on ``planner`` (arguments: :func:`check_planner`)."""
    record = CheckRecord(CHECKS)
    _, cls, implied = REGISTRY.resolve(planner)
    name = getattr(cls, "name", "")
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        record.fail("interface", f"'name' must be a kebab-case string like 'my-planner', got {name!r}")
    Config: Any = getattr(cls, "Config", None)
    if Config is None or not dataclasses.is_dataclass(Config):
        record.fail("interface", "'Config' must be a dataclass of the planner's settings (units in its docstrings)")
        record.skip(["settings"])
    elif config is None or isinstance(config, Mapping):
        settings = dict(config) if config is not None else None
        try:
            config = REGISTRY.configure(planner, settings).config
        except InvalidConfigError as exc:
            what = "Config() must work with defaults only" if not implied else f"{planner}'s settings {implied}"
            what = f"{planner}'s settings {settings}" if settings else what
            record.fail("settings", f"{what}: {exc}")
            record.skip(["interface", *RUN_CHECKS])  # its methods are not looked at either
            return record.report()
    else:
        record.skip(["settings"])  # a Config given: its defaults are not built
    for method in ("setup", "plan"):
        if not callable(getattr(cls, method, None)):
            record.fail("interface", f"missing method {method}()")
    if record.findings:
        record.skip(RUN_CHECKS)
        return record.report()

    def make() -> Any:
        return cls(config) if config is not None else REGISTRY.make(planner)

    trivial = trivial_problem()
    cases = problems or [trivial, blocked_problem()]
    if problems is not None:
        record.skip(["trivial-unsolved"])
    for problem in cases:
        label = f"on {problem.id}"
        try:
            result = plan(problem, make(), seed=seed, time_limit=time_limit)
        except Exception as exc:  # the harness itself should never raise for a planner bug
            record.fail("raises", f"{label}: the harness raised {type(exc).__name__}: {exc}")
            record.skip(RUN_CHECKS)
            continue
        if result.status is PlanStatus.ERROR:
            record.fail("raises", f"{label}: plan raised: {result.message}")
            record.skip(RUN_CHECKS)
            continue
        _result_checks(problem, result, record, label)
        if result.planning_time > 1.5 * time_limit + 0.5:
            took = f"took {result.planning_time:.2f} s with a time limit of {time_limit:.2f} s"
            record.fail("time-limit", f"{label}: {took}")
        ev = evaluate(problem, result)
        if result.status is PlanStatus.SUCCESS and not ev.success:
            record.fail("false-success", f"{label}: claims success but validation fails: {ev.failure}")
        if problem is trivial and problems is None and not ev.success:
            record.fail("trivial-unsolved", f"{label}: does not solve a trivial free-space problem ({ev.failure})")
        again = plan(problem, make(), seed=seed, time_limit=time_limit)
        if not _same_path(result, again):
            message = f"{label}: two runs with seed {seed} gave different paths (use only the rng handed in)"
            record.fail("non-deterministic", message)
    return record.report()


def _result_checks(problem: Problem, result: Any, record: CheckRecord, label: str) -> None:
    """The checks of a result's form (a path of the wrong shape is not looked at further)."""
    if not isinstance(result, PlanResult):
        record.fail("wrong-shape", f"{label}: plan() must return a PlanResult, got {type(result).__name__}")
        return
    if result.status is PlanStatus.SUCCESS and result.path is None:
        record.fail("wrong-shape", f"{label}: claims success without a path")
        return
    if result.path is not None:
        path = result.path
        if path.ndim != 2 or path.shape[1] != problem.robot.nq:
            record.fail("wrong-shape", f"{label}: path must be (N, {problem.robot.nq}), got {path.shape}")
            record.skip(["wrong-start", "non-finite"])
            return
        if len(path) == 0:
            record.fail("wrong-shape", f"{label}: path is empty; return path=None when there is none")
        elif not np.allclose(path[0], problem.start, atol=1e-6):
            record.fail("wrong-start", f"{label}: path[0] must equal problem.start")
        if not np.all(np.isfinite(path)):
            record.fail("non-finite", f"{label}: path contains NaN or infinite values")


def _same_path(a: PlanResult, b: PlanResult) -> bool:
    """Whether two runs with the same seed agree. A run cut by its time limit (``TIMEOUT``) got as
    far as the machine let it, so there the shorter path need only be the start of the longer: a
    loaded machine must not make a deterministic planner look unseeded."""
    clock = PlanStatus.TIMEOUT in (a.status, b.status)
    if a.status is not b.status and not clock:
        return False
    if a.path is None or b.path is None:
        return (a.path is None and b.path is None) or clock
    if clock:
        n = min(len(a.path), len(b.path))
        same_width = a.path.shape[1:] == b.path.shape[1:]
        return same_width and bool(np.allclose(a.path[:n], b.path[:n], atol=1e-9, rtol=0))
    return a.path.shape == b.path.shape and bool(np.allclose(a.path, b.path, atol=1e-9, rtol=0))

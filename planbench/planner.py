"""The planner interface every plugin implements, and the result it returns.

A planner is a class with a kebab-case ``name``, a frozen ``Config`` dataclass (units and defaults
documented on its fields), ``setup(problem)`` for untimed preparation (a field precompute, a
roadmap) and ``plan(problem, time_limit=..., rng=...)`` for the timed query. A failed plan is a
:class:`PlanStatus`, never an exception; an exception out of a planner is a bug, and the harness
records it as ``ERROR``. Randomness comes only from the ``rng`` handed in.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

if TYPE_CHECKING:
    from planbench.problem import Problem

__all__ = ["PlanStatus", "PlanResult", "Planner", "EmptyConfig"]


class PlanStatus(enum.Enum):
    """How a plan ended, as the planner reports it (the harness checks the path independently)."""

    SUCCESS = "success"
    LOCAL_MINIMUM = "local_minimum"  # progress stalled (potential-field planners)
    STEP_LIMIT = "step_limit"  # step or iteration budget spent
    TIMEOUT = "timeout"  # time limit reached
    COLLISION = "collision"  # the planner found its own path in collision
    INFEASIBLE = "infeasible"  # e.g. a QP without solution
    INVALID_START = "invalid_start"
    INVALID_GOAL = "invalid_goal"
    ERROR = "error"  # the planner raised; set by the harness
    CRASH = "crash"  # the planner's process died; set by the benchmark runner

    @property
    def solved(self) -> bool:
        return self is PlanStatus.SUCCESS


@dataclass(frozen=True, eq=False)
class PlanResult:
    """What a planner returns.

    ``path`` is an (N, nq) array of configurations with ``path[0] == problem.start``; ``times`` [s]
    are optional time stamps (N,), strictly increasing from 0, when the planner produces a
    trajectory. ``target`` says what the planner drove to: ``"configuration"`` (the goal joint
    vector; then the harness also checks the joint error) or ``"pose"``. ``info`` holds
    planner-specific diagnostics (JSON-friendly values or arrays).
    """

    status: PlanStatus
    path: np.ndarray | None = None
    times: np.ndarray | None = None
    target: str = "pose"
    message: str = ""
    info: Mapping[str, Any] = field(default_factory=dict)
    planning_time: float = float("nan")  # [s] measured by the harness, never by the planner
    setup_time: float = float("nan")  # [s] measured by the harness

    def __post_init__(self) -> None:
        if not isinstance(self.status, PlanStatus):
            raise TypeError(f"status must be a PlanStatus, got {self.status!r}")
        if self.target not in ("pose", "configuration"):
            raise ValueError(f"target must be 'pose' or 'configuration', got {self.target!r}")
        if self.path is not None:
            path = np.array(self.path, dtype=float)
            if path.ndim != 2:
                raise ValueError(f"path must be an (N, nq) array, got shape {path.shape}")
            path.setflags(write=False)
            object.__setattr__(self, "path", path)
        if self.times is not None:
            times = np.array(self.times, dtype=float)
            if self.path is None or times.shape != (len(self.path),):
                raise ValueError("times must have one entry per path row")
            times.setflags(write=False)
            object.__setattr__(self, "times", times)

    def replace(self, **changes: Any) -> PlanResult:
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class EmptyConfig:
    """A planner without settings."""


def build_config(Config: type, config: Any, settings: dict[str, Any]) -> Any:
    """A plugin's config: ``config`` with ``settings`` replaced, or ``Config(**settings)``
    (planners and controllers take their settings the same way)."""
    if config is None:
        return Config(**settings)
    return dataclasses.replace(config, **settings) if settings else config


class Planner:
    """Base class of planners (subclassing is optional: the protocol is what matters).

    Subclasses set ``name`` and ``Config`` and implement ``plan``; ``__init__`` takes a config
    instance, or keyword settings that build one.
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type] = EmptyConfig

    def __init__(self, config: Any = None, **settings: Any) -> None:
        self.config = build_config(self.Config, config, settings)

    def setup(self, problem: Problem) -> None:
        """Untimed preparation for ``problem`` (timed apart by the harness as setup time)."""

    def plan(self, problem: Problem, *, time_limit: float, rng: np.random.Generator) -> PlanResult:
        raise NotImplementedError

    # Optional: ``plot_result(self, problem, result, path_png)`` writes the planner's own figure of a
    # result to a PNG; ``planbench plan ... --plot out.png`` calls it when the planner has one.

"""Settings of ``matrix-field-guided``: the global planner, the tracking loop, the field.

Units: metres, radians, seconds.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from planbench.errors import InvalidConfigError, PlanbenchError
from planbench.field.scene_field import FieldSettings
from planbench.registry import REGISTRY
from planbench_plugins.ik_loop import check_number

__all__ = ["MatrixFieldGuidedConfig"]


@dataclass(frozen=True)
class MatrixFieldGuidedConfig(FieldSettings):
    """Settings of :class:`~planbench_plugins.matrix_field_guided.MatrixFieldGuidedPlanner`: the
    global planner, the tracking loop and the matrix field (:class:`FieldSettings`)."""

    # --- the global plan -----------------------------------------------------------------------
    global_planner: str = "ompl-rrtconnect"
    """Registered planner that gives the configuration waypoints (any planner returning a
    validated joint path)."""
    global_settings: Mapping[str, Any] = field(default_factory=dict)
    """Its settings, as ``planbench plan --set`` would give them."""
    global_time_share: float = 0.8
    """Share of the time limit [-] the global planner may use; the tracking gets the rest."""

    # --- tracking -------------------------------------------------------------------------------
    dt: float = 0.01
    """Integration time step [s]."""
    max_steps: int = 4000
    """Step budget of the tracking; spent, the global path is returned (``info["fallback"]``)."""
    velocity_scale: float = 0.5
    """The reference moves along the global path at this fraction of the joint velocity limits
    [-] (each segment's duration from its slowest joint); the commanded velocity may use the full
    limits."""
    tracking_gain: float = 10.0
    """``K`` [1/s] of the tracking term ``K (q_ref - q)``: a push of ``x`` rad/s holds the arm
    ``x / K`` rad off the reference."""
    max_lag: float = 0.1
    """[rad] Largest departure from the reference the push may cause: the push fades out (a
    smoothstep) as the largest joint error nears this, so the tracking always wins in the end and
    the arm passes an obstacle on the global path's side of it."""
    retries: int = 3
    """Tracked paths that the certified check refuses are tracked again, this many times, with
    the push off around each collision found (``quiet_before`` to ``quiet_after`` of reference
    time); then the global path itself is returned (``info["fallback"]``)."""
    quiet_before: float = 0.5
    """[s] The push stops this long before a collision found on an earlier try: time for the
    tracking error to decay onto the global path (by ``(1 - K dt)`` per step: 0.5 s at the default
    gain leaves 0.5 % of it)."""
    quiet_after: float = 0.3
    """[s] and stays off this long after it."""
    goal_tolerance: float = 1e-3
    """[rad] Largest joint error at which the tracked arm steps onto the global path's last
    configuration (the goal) and stops."""
    goal_fade: float = 0.3
    """[rad] The push fades to 0 over this much joint path length before the goal (a smoothstep),
    so goals next to obstacles (grasps) are reached as the global planner found them."""

    # --- the push (the matrix field, as matrix-field's) ---------------------------------------
    speed_max: float = 0.25
    """Speed [m/s] of the push on a point ``standoff`` from a flat wall (with ``repulsion_gain``
    1): the unit the field's gain is derived in, as in ``matrix-field``."""
    standoff: float = 0.10
    """Distance [m] from a flat wall at which a point on the arm is pushed at ``speed_max``."""
    repulsion_gain: float = 2.0
    """Multiplier [-] of the gain derived from ``standoff``; 0 tracks the global path alone.
    Chosen on MotionBenchMaker 0001-0020 (140 problems, 5 s, seed 0): median smallest clearance
    6.2 mm at 2, 5.7 mm at 1, RRT-Connect's own path 0.48 mm; all 140 solved either way."""
    control_point_spacing: float = 0.12
    """Largest distance between control points along a link [m] (automatic placement)."""
    control_points: Any = None
    """Per-link override of the automatic placement, as in ``matrix-field``."""

    def __post_init__(self) -> None:
        if not isinstance(self.global_settings, Mapping):
            raise InvalidConfigError(f"global_settings must be a mapping of settings, got {self.global_settings!r}")
        object.__setattr__(self, "global_settings", dict(self.global_settings))
        if not isinstance(self.global_planner, str) or self.global_planner.startswith("matrix-field-guided"):
            raise InvalidConfigError(
                f"global_planner must name another registered planner (e.g. 'ompl-rrtconnect'), got "
                f"{self.global_planner!r}"
            )
        for name in (
            "dt",
            "velocity_scale",
            "tracking_gain",
            "max_lag",
            "goal_tolerance",
            "quiet_before",
            "quiet_after",
            "speed_max",
            "standoff",
            "control_point_spacing",
        ):
            check_number(self, name, lambda v: v > 0, "finite and > 0")
        check_number(self, "goal_fade", lambda v: v >= 0, "finite and >= 0")
        check_number(self, "repulsion_gain", lambda v: v >= 0, "finite and >= 0")
        check_number(self, "global_time_share", lambda v: 0 < v <= 1, "in (0, 1]")
        check_number(self, "velocity_scale", lambda v: v <= 1, "in (0, 1]")
        if self.tracking_gain * self.dt > 1:
            raise InvalidConfigError(
                f"tracking_gain ({self.tracking_gain:g} 1/s) times dt ({self.dt:g} s) must be at most 1: "
                "a larger gain overshoots the reference in one step"
            )
        if isinstance(self.max_steps, bool) or not isinstance(self.max_steps, int) or self.max_steps < 1:
            raise InvalidConfigError(f"max_steps must be an integer >= 1, got {self.max_steps!r}")
        if isinstance(self.retries, bool) or not isinstance(self.retries, int) or self.retries < 0:
            raise InvalidConfigError(f"retries must be an integer >= 0, got {self.retries!r}")
        self.validate_field()
        # the global planner's settings are checked now, as every planner's are, not at its first plan
        try:
            REGISTRY.resolve(self.global_planner)
        except PlanbenchError as exc:
            raise InvalidConfigError(f"global_planner {self.global_planner!r} refused: {exc}") from None
        try:
            REGISTRY.configure(self.global_planner, self.global_settings)
        except PlanbenchError as exc:
            raise InvalidConfigError(f"global_settings {self.global_settings!r} refused: {exc}") from None

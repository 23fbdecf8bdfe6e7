"""``mppi``: a sampling model-predictive controller (model-predictive path integral control, the
family of STORM) on the observed grid's distance field; a baseline of another family than the
fields and the replanners.

**Each tick** (``step``) it keeps a mean sequence of joint velocities over a short horizon
(``horizon_steps`` steps of ``horizon_dt`` s), draws ``samples`` perturbed copies of it (Gaussian
noise of ``noise`` times each joint's velocity limit, correlated in time by ``noise_smoothing``),
clips every velocity to the limits the controller uses (``speed_scale`` times the robot's), rolls
each sequence out from the arm's configuration (``q += dt qd``, clamped to the joint limits) and
scores it: the end effector's distance to the goal pose (position [m] and the rotation's angle
[rad]) at every step and more at the last one, the control points' spheres near or inside
observed obstacles (the distance field below), pairs of spheres of links that may touch each other
(the robot's collision pairs, SRDF exclusions removed), velocity commanded into a joint limit,
and the change of velocity from step to step. The new mean is the average of the samples weighted
by ``exp(-(cost - min cost) / temperature)``; its first velocity is the command, and the sequence,
shifted by one control period, is the next tick's mean (warm start). Three samples are not random:
the mean itself, standing still, and the damped-least-squares velocity straight at the goal pose
(joints at a limit it would push into left out); a fourth goes straight at the goal configuration
in joint space when the task gives one. Both decay over the horizon as the first-order law they
start would (``exp(-goal_gain t)``), so that the controller reaches a goal in free space as
precisely as a resolved-rate law, and it can always choose to stop. Within ``goal_fade`` of the
goal the clearance cost fades with the end effector's distance to it (a grasp comes close to what
is there); a collision costs the same everywhere.

**The command is checked** against the arm itself and the observed scene: when the new mean's
rollout has a sphere in an obstacle or in another link earlier than the best sample's, the best
sample is commanded (and becomes the mean) instead (``info()["fallbacks"]``). The command is
cut so that the arm stays within its joint limits over the control period.

**Kinematics** in the rollouts: a compiled forward kinematics from the model's joint placements
(revolute and prismatic joints; checked against pinocchio in ``setup``), the IK loop's control
points (:func:`~planbench_plugins.ik_loop.place_control_points`: spheres along each moving link).
Pinocchio's forward kinematics per rollout step from Python, with the joint placements read back
through the bindings, cost 6.5 ms for the default 64 x 12 rollout steps before any cost; a Jacobian
linearised at the current configuration is wrong by centimetres over half a second of motion. All
rollouts and their costs are one compiled call (docs/reactive.md, "mppi").

**The distance field** (``update``, per frame): the exact Euclidean distance transform
(:func:`._mppi_compiled.distance_block`) of the observed grid's occupied cells in a block around
the arm: the control points where the arm is, grown by ``field_reach`` (how far a rollout can
take them) plus ``obstacle_margin`` and the largest link radius. A rollout point beyond the block
reads "no obstacle"; only the occupied cells' box grown by the distances the costs use is
transformed. On the whole grid (142^3 cells for the Panda) scipy's transform costs hundreds of
milliseconds a frame; the block a few (docs/reactive.md, "mppi"). A cell occupied after frames saw
it free for ``moving_free_time`` without a break (within ``moving_window``) is a moving obstacle's
for ``moving_window``: such cells can be grown by ``moving_inflation`` first (off by default; motion
is not predicted otherwise).

**Unknown cells** (``unknown``, :class:`.unknown.UnknownSettings`): with ``"occupied"`` the unknown
cells near the arm (:func:`.unknown.near_unknown`, where the last step left it) are occupied in
the grid the distance field is computed from; ``"free"`` (default) reads them free.

numba is required (the rollouts are compiled); randomness comes only from the ``rng`` of ``reset``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from planbench.errors import InvalidConfigError
from planbench.geometry.occupancy import OccupancyGrid
from planbench.problem import Goal
from planbench.reactive.controller import Controller, ControlTask, Observation
from planbench.robot import link_of
from planbench_plugins.controllers.unknown import UnknownSettings, near_unknown
from planbench_plugins.ik_loop import place_control_points

__all__ = ["MPPIController", "MPPIConfig", "ChainModel"]


@dataclass(frozen=True)
class MPPIConfig(UnknownSettings):
    """Settings of ``mppi`` (module docstring). Costs are per rollout step, added over the horizon."""

    samples: int = 64
    """Rollouts per tick (three or four of them not random: the mean, standing still, straight at the
    goal pose, straight at the goal configuration when the task gives one)."""
    horizon_steps: int = 12
    """Steps of a rollout."""
    horizon_dt: float = 0.04
    """[s] length of a rollout step (the horizon is ``horizon_steps * horizon_dt``)."""
    noise: float = 0.3
    """Standard deviation of the velocity noise, a fraction of each joint's velocity limit."""
    noise_smoothing: float = 0.6
    """Correlation of the noise from one rollout step to the next, in [0, 1)."""
    temperature: float = 0.2
    """MPPI's lambda, in units of cost: lower follows the best samples more closely."""
    speed_scale: float = 0.5
    """Fraction of the robot's joint velocity limits the controller commands, in (0, 1]."""
    goal_gain: float = 3.0
    """[1/s] gain of the straight-at-the-goal sample (pose error to end-effector velocity)."""
    position_weight: float = 5.0
    """Cost per metre of end-effector distance to the goal, every step."""
    orientation_weight: float = 1.0
    """Cost per radian of the end effector's rotation error (the angle), every step."""
    terminal_weight: float = 10.0
    """The goal costs at the last step are counted this many more times."""
    obstacle_weight: float = 1.0
    """Cost of a sphere touching an obstacle's surface, falling quadratically to 0 at
    ``obstacle_margin`` from it, per sphere and step."""
    obstacle_margin: float = 0.10
    """[m] clearance of a sphere below which the obstacle cost starts."""
    goal_fade: float = 0.15
    """[m] within this distance of the goal position the end effector's rollout step counts the
    obstacle clearance cost times ``distance / goal_fade`` (at least ``fade_floor``): at the goal the
    arm must come close to what is there (a collision still costs ``collision_cost``). 0: off."""
    fade_floor: float = 0.1
    """Smallest factor of the clearance cost near the goal, in [0, 1]."""
    moving_window: float = 0.5
    """[s] a cell occupied after a run of frames that saw it free, ended within this long, is a
    moving obstacle's, and stays one this long."""
    moving_free_time: float = 0.2
    """[s] a cell counts as a moving obstacle's only when frames saw it free this long without a
    break before it was occupied (the noisy cells at a still surface flicker between the two)."""
    moving_self_margin: float = 0.05
    """[m] cells within a link's radius plus this of a control point never count as moving: the
    arm's own surface, where the sensor's robot filter (0.03 m) lets a noisy point through."""
    moving_inflation: float = 0.0
    """[m] a moving obstacle's cells are grown by this in the distance field (the obstacles'
    motion over the horizon is not predicted otherwise): its rollouts keep that much more clear.
    0 (default): off. Chosen on 12 fast depth scenarios of ``dynamic-tune``: 7 of 12 solved with 0
    and with 0.1; 0.1 traded 5 collisions with moving obstacles for 4 goals not reached (the
    Panda's, kept out by still surfaces taken for moving ones), 8 missed deadlines a run (median)
    against 0 (docs/reactive.md, "mppi")."""
    collision_cost: float = 1000.0
    """Cost of a sphere inside an obstacle or another link, per sphere and step."""
    self_weight: float = 2.0
    """As ``obstacle_weight``, for two spheres of links that may touch each other."""
    self_margin: float = 0.03
    """[m] clearance between two such spheres below which their cost starts."""
    limit_weight: float = 1.0
    """Cost per (rad/s)^2 of velocity a joint limit cuts off in a rollout (commanded into the limit)."""
    smoothness_weight: float = 0.01
    """Cost per (rad/s)^2 of velocity change between rollout steps (and from the last command)."""
    field_reach: float = 0.3
    """[m] the distance field covers the control points grown by this (and the margin, a radius)."""
    control_point_spacing: float = 0.12
    """[m] largest gap between control points of one link (the IK loop's placement)."""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise :class:`~planbench.errors.InvalidConfigError` naming the first bad setting."""
        ints = {"samples": 5, "horizon_steps": 1}
        for name, low in ints.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise InvalidConfigError(f"{name} must be an integer >= {low}, got {v!r}")
        for f in fields(self):
            if f.name in ints or f.name.startswith("unknown"):
                continue
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise InvalidConfigError(f"{f.name} must be a finite number >= 0, got {v!r}")
        for name in ("horizon_dt", "temperature", "speed_scale", "field_reach", "control_point_spacing"):
            if getattr(self, name) <= 0:
                raise InvalidConfigError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if self.speed_scale > 1:
            raise InvalidConfigError(
                f"speed_scale must be in (0, 1] (of the velocity limits), got {self.speed_scale!r}"
            )
        if self.fade_floor > 1:
            raise InvalidConfigError(f"fade_floor must be in [0, 1], got {self.fade_floor!r}")
        if self.noise_smoothing >= 1:
            raise InvalidConfigError(f"noise_smoothing must be in [0, 1), got {self.noise_smoothing!r}")
        self.validate_unknown()


def _compiled() -> Any:
    try:
        from planbench_plugins.controllers import _mppi_compiled
    except ImportError as exc:  # pragma: no cover - numba is a dependency
        raise RuntimeError("mppi needs numba (its rollouts are compiled): pip install numba") from exc
    return _mppi_compiled


class ChainModel:
    """A robot's kinematic tree as arrays for the compiled forward kinematics (module docstring):
    ``parent``, ``kind`` (0 revolute, 1 prismatic), ``axis`` (unit, in the joint frame), the
    placement in the parent ``Rp``/``tp``, the configuration index ``iq`` of every joint."""

    REVOLUTE = {"JointModelRX": (1, 0, 0), "JointModelRY": (0, 1, 0), "JointModelRZ": (0, 0, 1)}
    PRISMATIC = {"JointModelPX": (1, 0, 0), "JointModelPY": (0, 1, 0), "JointModelPZ": (0, 0, 1)}

    def __init__(self, model: Any) -> None:
        nj = int(model.njoints)
        self.parent = np.array(list(model.parents), dtype=np.int64)
        self.kind = np.zeros(nj, dtype=np.int64)
        self.axis = np.zeros((nj, 3))
        self.Rp = np.zeros((nj, 3, 3))
        self.tp = np.zeros((nj, 3))
        self.iq = np.zeros(nj, dtype=np.int64)
        self.Rp[0] = np.eye(3)
        for j in range(1, nj):
            joint = model.joints[j]
            kind = joint.shortname()
            if kind in self.REVOLUTE:
                self.axis[j] = self.REVOLUTE[kind]
            elif kind in self.PRISMATIC:
                self.kind[j], self.axis[j] = 1, self.PRISMATIC[kind]
            elif kind in ("JointModelRevoluteUnaligned", "JointModelPrismaticUnaligned"):
                self.kind[j] = int(kind == "JointModelPrismaticUnaligned")
                self.axis[j] = np.asarray(joint.extract().axis, dtype=float)
            else:
                raise ValueError(f"mppi: joint {model.names[j]!r} is a {kind}; only revolute and prismatic joints")
            if joint.nq != 1:
                raise ValueError(f"mppi: joint {model.names[j]!r} has {joint.nq} coordinates, expected 1")
            M = model.jointPlacements[j]
            self.Rp[j], self.tp[j] = M.rotation, M.translation
            self.iq[j] = joint.idx_q
        self.R = np.zeros((nj, 3, 3))
        self.R[0] = np.eye(3)
        self.t = np.zeros((nj, 3))

    def forward(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every joint's world rotation (nj, 3, 3) and position (nj, 3) at ``q`` (buffers, reused)."""
        _compiled().forward(
            np.asarray(q, dtype=float), self.parent, self.kind, self.axis, self.Rp, self.tp, self.iq, self.R, self.t
        )
        return self.R, self.t


def base_points(robot: Any, spacing: float) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """Spheres on the links fixed to the base (joint 0), for the self-collision pairs (the IK loop's
    control points leave them out: no joint moves them): each link's collision geometries bounded
    by one box in the base frame, points along its long axis at most ``spacing`` apart, the radius
    half the larger cross-section, as :func:`~planbench_plugins.ik_loop.place_control_points` does.
    Positions (N, 3) [m], radii (N,) [m], link names."""
    corners01 = np.array(list(np.ndindex(2, 2, 2)), dtype=float)
    per_link: dict[str, list[np.ndarray]] = {}
    for g in robot.collision_model.geometryObjects:
        if g.parentJoint != 0:
            continue
        geom = g.geometry
        geom.computeLocalAABB()
        lo, hi = np.array(geom.aabb_local.min_), np.array(geom.aabb_local.max_)
        corners = lo + corners01 * (hi - lo)
        per_link.setdefault(link_of(g.name), []).append(corners @ g.placement.rotation.T + g.placement.translation)
    local, radius, links = [], [], []
    for name, items in per_link.items():
        pts = np.concatenate(items)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        ext, centre = hi - lo, 0.5 * (lo + hi)
        a = int(np.argmax(ext))
        r = 0.5 * float(max(ext[b] for b in range(3) if b != a))
        half = max(0.5 * float(ext[a]) - r, 0.0)
        n = int(math.ceil(2 * half / spacing - 1e-9)) + 1 if 2 * half > 0.1 * spacing else 1
        for s in np.linspace(-half, half, n) if n > 1 else np.zeros(1):
            p = centre.copy()
            p[a] += s
            local.append(p)
            radius.append(r)
            links.append(name)
    return np.array(local, dtype=float).reshape(-1, 3), np.array(radius, dtype=float), tuple(links)


class MPPIController(Controller):
    """A sampling model-predictive controller (module docstring). Settings: :class:`MPPIConfig`."""

    name = "mppi"
    Config = MPPIConfig

    def __init__(self, config: Any = None, **settings: Any) -> None:
        super().__init__(config, **settings)
        self.task: ControlTask | None = None
        self._rng = np.random.default_rng(0)

    # --- setup ----------------------------------------------------------------------------------
    def setup(self, task: ControlTask) -> None:
        """Kinematics, control points, self-collision pairs and buffers for ``task`` (untimed)."""
        import pinocchio as pin

        c = self.config
        self.kc = _compiled()
        robot = task.robot
        model = robot.model
        self.task = task
        self.chain = chain = ChainModel(model)
        self.n = n = int(model.nq)
        frame = model.frames[robot.frame_id(task.goal.pose.frame)]
        self.ee_joint = int(frame.parentJoint)
        self.ee_R = np.ascontiguousarray(frame.placement.rotation)
        self.ee_t = np.ascontiguousarray(frame.placement.translation)
        points = place_control_points(robot, c.control_point_spacing)
        self.n_move = len(points)
        base = base_points(robot, c.control_point_spacing)
        self.cp_joint = np.ascontiguousarray(
            np.concatenate((points.joint, np.zeros(len(base[0]), dtype=int))), dtype=np.int64
        )
        self.cp_local = np.ascontiguousarray(np.concatenate((points.local, base[0])).reshape(-1, 3), dtype=float)
        self.cp_radius = np.ascontiguousarray(np.concatenate((points.radius, base[1])), dtype=float)
        self.cp_link = tuple(points.link) + base[2]
        self.lo = np.asarray(robot.lower, dtype=float).copy()
        self.hi = np.asarray(robot.upper, dtype=float).copy()
        self.vmax = c.speed_scale * np.asarray(robot.velocity_limit, dtype=float)
        # the compiled kinematics must be pinocchio's: checked at the start and the home
        data = model.createData()
        for q in (np.asarray(task.start, dtype=float), np.asarray(robot.home, dtype=float)):
            pin.forwardKinematics(model, data, q)
            R, t = chain.forward(q)
            for j in range(1, model.njoints):
                if not (
                    np.allclose(R[j], data.oMi[j].rotation, atol=1e-9)
                    and np.allclose(t[j], data.oMi[j].translation, atol=1e-9)
                ):
                    raise RuntimeError(f"mppi: compiled kinematics disagree with pinocchio at joint {model.names[j]}")
        self.pairs = self._self_pairs(robot, [task.start, robot.home] + ([] if task.goal.q is None else [task.goal.q]))
        self.weights = np.array(
            [
                c.position_weight,
                c.orientation_weight,
                c.terminal_weight * c.position_weight,
                c.terminal_weight * c.orientation_weight,
                c.obstacle_weight,
                c.obstacle_margin,
                c.collision_cost,
                c.self_weight,
                c.self_margin,
                c.limit_weight,
                c.smoothness_weight,
                c.goal_fade,
                c.fade_floor,
            ]
        )
        K, T = c.samples, c.horizon_steps
        self.V = np.zeros((K, T, n))
        self.cost = np.zeros(K)
        self.hit = np.zeros(K, dtype=np.int64)
        self._one_V = np.zeros((1, T, n))
        self._one_cost = np.zeros(1)
        self._one_hit = np.zeros(1, dtype=np.int64)
        self.sigma = c.noise * self.vmax
        self.shift = float(task.period) / c.horizon_dt
        self._no_field: np.ndarray = np.zeros((0, 0, 0), dtype=np.float32)
        # distances beyond the clearance costs' reach are not needed: the transform stops there
        self.field_cap = c.obstacle_margin + float(self.cp_radius[: self.n_move].max(initial=0.0)) + 0.05
        self._reset_state(np.asarray(task.start, dtype=float))

    def _self_pairs(self, robot: Any, valid: list[Any]) -> np.ndarray:
        """Pairs of control points on links that the collision model lets touch, less those whose
        spheres overlap at a configuration known to be free of self-collision (the start, home,
        the goal configuration): the spheres are coarser than the links there."""
        gm = robot.collision_model
        links = set()
        for pair in gm.collisionPairs:
            a = link_of(gm.geometryObjects[pair.first].name)
            b = link_of(gm.geometryObjects[pair.second].name)
            links.add((a, b))
            links.add((b, a))
        link, joint = self.cp_link, self.cp_joint
        cand = [
            (i, j)
            for i in range(len(link))
            for j in range(i + 1, len(link))
            if (link[i], link[j]) in links and joint[i] != joint[j]
        ]
        keep = []
        r = self.cp_radius
        spots = []
        for q in valid:
            R, t = self.chain.forward(np.asarray(q, dtype=float))
            spots.append(np.einsum("nij,nj->ni", R[self.cp_joint], self.cp_local) + t[self.cp_joint])
        for i, j in cand:
            if all(np.linalg.norm(p[i] - p[j]) - r[i] - r[j] > 0 for p in spots):
                keep.append((i, j))
        return np.array(keep, dtype=np.int64).reshape(-1, 2)

    # --- a run ----------------------------------------------------------------------------------
    def _reset_state(self, q: np.ndarray) -> None:
        T, n = self.config.horizon_steps, self.n
        self.U = np.zeros((T, n))
        self.qd_prev = np.zeros(n)
        self.q = q.copy()
        self.dist = self._no_field
        self.forigin = np.zeros(3)
        self.fres = 1.0
        self._counted: np.ndarray | None = None
        self._cell_state: np.ndarray | None = None  # per cell: free since, last seen free, marked
        self._stats = {"steps": 0, "frames": 0, "fallbacks": 0, "best_hits": 0, "unknown_cells": 0, "moving_cells": 0}
        self._field_cells = 0

    def reset(self, q: np.ndarray, rng: np.random.Generator) -> None:
        """A new run from ``q``: the mean sequence at rest, no obstacle known."""
        self._require()
        self._rng = rng
        self._reset_state(np.asarray(q, dtype=float))

    def _require(self) -> ControlTask:
        if self.task is None:
            raise RuntimeError("mppi: call setup(task) before reset, update or step")
        return self.task

    def _points(self, q: np.ndarray) -> np.ndarray:
        R, t = self.chain.forward(q)
        return np.einsum("nij,nj->ni", R[self.cp_joint], self.cp_local) + t[self.cp_joint]

    def update(self, observation: Observation) -> None:
        """The distance field of the new frame in a block around the arm (module docstring)."""
        self._require()
        c = self.config
        grid = observation.grid
        pts = self._move_points()
        unknown = None
        if c.unknown == "occupied" and grid.known is not None:
            unknown = near_unknown(
                grid, [(pts, self.cp_radius[: self.n_move])], c.unknown_reach, c.unknown_self_margin, self._counted
            )
            self._counted = unknown
            self._stats["unknown_cells"] = 0 if unknown is None else int(np.count_nonzero(unknown))
        self._stats["frames"] += 1
        grow = c.field_reach + c.obstacle_margin + float(self.cp_radius[: self.n_move].max(initial=0.0))
        lo_idx = np.floor((pts.min(axis=0) - grow - grid.origin) / grid.resolution).astype(int)
        hi_idx = np.ceil((pts.max(axis=0) + grow - grid.origin) / grid.resolution).astype(int)
        lo_idx = np.clip(lo_idx, 0, grid.shape)
        hi_idx = np.clip(hi_idx, 0, grid.shape)
        if np.any(hi_idx <= lo_idx):
            self.dist = self._no_field
            return
        sl = tuple(slice(a, b) for a, b in zip(lo_idx, hi_idx, strict=True))
        occupied = np.asarray(grid.data[sl]) >= 0.5
        moving = self._moving(grid, sl, occupied, observation.time)
        self._stats["moving_cells"] = 0
        if moving is not None:  # the arm's own cells (the sensor's filter misses some) do not move in
            block_origin = grid.origin + lo_idx * grid.resolution
            radii = self.cp_radius[: self.n_move]
            if not self.kc.drop_near(moving, block_origin, grid.resolution, pts, radii, c.moving_self_margin):
                moving = None
        if unknown is not None:
            occupied |= unknown[sl]
        if moving is not None:
            self._stats["moving_cells"] = int(np.count_nonzero(moving))
            self.kc.grow_into(moving, c.moving_inflation / grid.resolution, occupied)
        if not occupied.any():
            self.dist = self._no_field
            self._field_cells = 0
            return
        # only the occupied cells' box grown by the cap is transformed: beyond it every distance
        # is the cap, which a rollout point outside the field reads anyway (the same costs)
        grow_cells = int(math.ceil(self.field_cap / grid.resolution)) + 1
        columns = np.asarray(occupied.any(axis=2))  # an array: occupied is 3D
        xs, ys = np.flatnonzero(columns.any(axis=1)), np.flatnonzero(columns.any(axis=0))
        zs = np.flatnonzero(occupied[xs[0] : xs[-1] + 1, ys[0] : ys[-1] + 1].any(axis=(0, 1)))
        lo_occ = np.maximum(np.array([xs[0], ys[0], zs[0]]) - grow_cells, 0)
        hi_occ = np.minimum(np.array([xs[-1], ys[-1], zs[-1]]) + 1 + grow_cells, occupied.shape)
        occupied = np.ascontiguousarray(occupied[lo_occ[0] : hi_occ[0], lo_occ[1] : hi_occ[1], lo_occ[2] : hi_occ[2]])
        dist: np.ndarray = np.empty(occupied.shape, dtype=np.float32)
        self.kc.distance_block(occupied, grid.resolution, self.field_cap, dist)
        self.dist = dist
        self.forigin = grid.origin + (lo_idx + lo_occ) * grid.resolution
        self.fres = float(grid.resolution)
        self._field_cells = int(dist.size)

    def _moving(self, grid: OccupancyGrid, sl: tuple[slice, ...], occupied: np.ndarray, t: float) -> np.ndarray | None:
        """The cells of the block ``sl`` occupied now that count as a moving obstacle's: occupied
        after frames saw them free (known, not occupied) for ``moving_free_time`` s without a
        break, that run ending within ``moving_window`` s, and for ``moving_window`` s after that
        (:func:`._mppi_compiled.moving_cells`); None when none or the setting is off. The state is
        kept per cell of the grid; only the block's cells are visited."""
        c = self.config
        if c.moving_inflation <= 0 or c.moving_window <= 0:
            return None
        if self._cell_state is None or self._cell_state.shape[1:] != grid.shape:
            self._cell_state = np.empty((3, *grid.shape), dtype=np.float32)
            self._cell_state[0] = np.inf  # free since: not free
            self._cell_state[1:] = -np.inf  # last seen free, marked: never
        state = self._cell_state
        known = np.ones_like(occupied) if grid.known is None else np.asarray(grid.known[sl])
        moving = np.zeros_like(occupied)
        count = self.kc.moving_cells(
            occupied,
            known,
            state[0][sl],
            state[1][sl],
            state[2][sl],
            float(t),
            c.moving_window,
            c.moving_free_time,
            moving,
        )
        return moving if count else None

    def _goal_velocity(self, q: np.ndarray, goal: Goal) -> np.ndarray:
        """Damped least squares straight at the goal pose from ``q`` (``goal_gain`` times the pose
        error; joints at a limit that it would push into are left out), within the velocity limits."""
        import pinocchio as pin

        R, t = self.chain.forward(q)
        j = self.ee_joint
        Ree = R[j] @ self.ee_R
        pee = R[j] @ self.ee_t + t[j]
        err = np.concatenate((goal.pose.position - pee, pin.log3(goal.pose.rotation @ Ree.T)))
        J = np.zeros((6, self.n))
        k = j
        while k > 0:
            w = R[k] @ self.chain.axis[k]
            col = int(self.chain.iq[k])
            if self.chain.kind[k] == 1:
                J[:3, col] = w
            else:
                J[:3, col] = np.cross(w, pee - t[k])
                J[3:, col] = w
            k = int(self.chain.parent[k])
        target = self.config.goal_gain * err
        free = np.ones(self.n, dtype=bool)
        for _ in range(2):  # joints at a limit that the answer pushes into are left out, once
            Jf = J * free
            qd = Jf.T @ np.linalg.solve(Jf @ Jf.T + 0.05**2 * np.eye(6), target)
            into = ((q <= self.lo + 1e-6) & (qd < 0)) | ((q >= self.hi - 1e-6) & (qd > 0))
            if not into.any():
                break
            free &= ~into
        qd *= free
        scale = np.max(np.abs(qd) / self.vmax)
        return qd / scale if scale > 1 else qd

    def step(self, t: float, q: np.ndarray, observation: Observation | None, goal: Goal) -> np.ndarray:
        """One MPPI update from ``q`` [rad]: the first velocity [rad/s] of the new mean sequence."""
        self._require()
        c = self.config
        q = np.asarray(q, dtype=float)
        self.q = q.copy()
        K, T, n = c.samples, c.horizon_steps, self.n
        U, V, vmax = self.U, self.V, self.vmax
        noise = self._rng.standard_normal((K, T, n))
        a = c.noise_smoothing
        for s in range(1, T):
            noise[:, s] = a * noise[:, s - 1] + math.sqrt(1.0 - a * a) * noise[:, s]
        np.multiply(noise, self.sigma, out=V)
        V += U
        V[0] = U
        V[1] = 0.0
        # the straight samples slow down as the first-order law they start would: exp(-gain t)
        decay = np.exp(-c.goal_gain * c.horizon_dt * np.arange(T))[:, None]
        V[2] = decay * self._goal_velocity(q, goal)
        if goal.q is not None:  # straight at the goal configuration, in joint space
            qd_goal = c.goal_gain * (np.asarray(goal.q, dtype=float) - q)
            scale = np.max(np.abs(qd_goal) / vmax)
            V[3] = decay * (qd_goal / scale if scale > 1 else qd_goal)
        np.clip(V, -vmax, vmax, out=V)
        pg = np.asarray(goal.pose.position, dtype=float)
        Rg = np.ascontiguousarray(goal.pose.rotation, dtype=float)
        self._rollouts(q, V, pg, Rg, self.cost, self.hit)
        cost = self.cost
        best = int(np.argmin(cost))
        w = np.exp(-(cost - cost[best]) / c.temperature)
        w /= w.sum()
        mean = np.tensordot(w, V, axes=1)
        np.clip(mean, -vmax, vmax, out=mean)
        # the check: the new mean must not hit something earlier than the best sample
        self._one_V[0] = mean
        self._rollouts(q, self._one_V, pg, Rg, self._one_cost, self._one_hit)
        if self._one_hit[0] < self.hit[best]:
            mean = V[best].copy()
            self._stats["fallbacks"] += 1
        if self.hit[best] < T:
            self._stats["best_hits"] += 1
        # the command keeps the arm within its joint limits over the control period
        period = self.task.period  # type: ignore[union-attr]
        qd = np.clip(mean[0], (self.lo - q) / period, (self.hi - q) / period)
        # warm start: the sequence shifted by one control period (the last velocity held)
        src = np.arange(T) + self.shift
        i0 = np.minimum(np.floor(src).astype(int), T - 1)
        i1 = np.minimum(i0 + 1, T - 1)
        f = np.clip(src - np.floor(src), 0.0, 1.0)[:, None]
        self.U = (1.0 - f) * mean[i0] + f * mean[i1]
        self.qd_prev = qd
        self._stats["steps"] += 1
        return qd

    def _rollouts(
        self, q: np.ndarray, V: np.ndarray, pg: np.ndarray, Rg: np.ndarray, cost: np.ndarray, hit: np.ndarray
    ) -> None:
        ch = self.chain
        self.kc.rollout_costs(
            q,
            V,
            self.config.horizon_dt,
            self.lo,
            self.hi,
            ch.parent,
            ch.kind,
            ch.axis,
            ch.Rp,
            ch.tp,
            ch.iq,
            self.cp_joint,
            self.cp_local,
            self.cp_radius,
            self.n_move,
            self.ee_joint,
            self.ee_R,
            self.ee_t,
            self.pairs,
            self.dist,
            self.forigin,
            self.fres,
            pg,
            Rg,
            self.qd_prev,
            self.weights,
            cost,
            hit,
        )

    def _move_points(self) -> np.ndarray:
        return self._points(self.q)[: self.n_move]

    def info(self) -> dict[str, Any]:
        """Ticks and frames of the run; ``fallbacks``: ticks whose mean was replaced by the best
        sample (it hit something sooner); ``best_hits``: ticks at which even the best sample's
        rollout hit something; the control points, self-collision pairs and the last field's cells."""
        out: dict[str, Any] = dict(self._stats)
        out["n_control_points"] = int(len(self.cp_joint)) if self.task is not None else 0
        out["self_pairs"] = int(len(self.pairs)) if self.task is not None else 0
        out["field_cells"] = self._field_cells
        return out

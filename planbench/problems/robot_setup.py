"""``planbench robot add``: a robot settings file (TOML) for a URDF, proposed the way MoveIt's setup
assistant proposes one.

:func:`propose` reads the URDF (and an SRDF when given; a relative path not found from the working
folder is looked up in example-robot-data's ``robots/`` folder, as a settings file's are) and
proposes:

- **the planned joints**: the movable joints (revolute, continuous, prismatic) on the chain from the
  root link to the tool frame; every other movable joint (a gripper's, say) is held fixed at its
  default value, MoveIt's: 0, or the middle of its range when 0 is outside it (``fixed``: more
  joints to hold, at their default or at a value);
- **continuous joints**: planned over :data:`planbench.robot.CONTINUOUS_RANGE`, ``[-pi, pi]`` (one
  full turn), written under ``[position_limits]`` where the user may widen it;
- **the tool frame** (``ee_frame``): the one asked for; else the SRDF's ``<end_effector
  parent_link>``, else the tip link of an SRDF group's ``<chain>``; else the URDF's leaf link with the
  most movable joints above it, ties broken by a name with ``tool``, ``flange``, ``end_effector``,
  ``eef``, ``ee`` in it (in that order), then by the last in the file;
- **collision pairs to disable** (``ignore_collision_pairs``), as MoveIt's setup assistant computes
  them (``moveit_setup_assistant``'s ``compute_default_collisions``), link pair by link pair, each for
  the first reason that holds: ``adjacent`` (parent and child in the kinematic tree; a link without
  collision geometry is skipped, its children counting as adjacent to its nearest ancestor that has
  some); ``always`` (in collision in at least :data:`ALWAYS_FRACTION` of the random configurations,
  MoveIt's default 95 %); ``default`` (in collision at the default configuration, every joint at its
  default value, and in none of the random configurations); ``never`` (in collision in none of the
  random configurations). Two departures from MoveIt, which tests ``default`` before ``always`` and
  disables every pair touching at the default configuration: a pair both ``always`` and touching
  there is labelled ``always`` (the same pairs disabled); a pair touching there that also touches in
  some random configurations and is apart in others stays checked (``default_kept``: a folded rest
  pose whose links touch, such as the Unitree Z1's, does not make a real collision invisible).
  The random configurations are :data:`DEFAULT_SAMPLES` (``samples``) uniform draws
  over the joint ranges from ``numpy.random.default_rng(seed)``, so the same inputs give the same
  file. Pairs the SRDF's ``disable_collisions`` already remove are not checked again (the file
  names the SRDF). Like MoveIt's, ``never`` is a sampled verdict: a pair that collides only in a
  sliver of the joint space may be disabled (more samples make that less likely);
- **home**: the first of the SRDF's ``<group_state>`` configurations that names every planned joint
  and is collision-free with the pairs kept (and the ``default`` ones: home does not lean on the
  assumption that disabled them), else the middle of the ranges, else the default
  configuration, else the collision-free random configuration nearest the middle.

:func:`settings_text` writes the proposal as a commented TOML file for
:func:`planbench.robot.load_robot`, and :func:`plan_check` plans with it (OMPL RRT-Connect, empty
scene, from home to a random collision-free configuration at least 1 rad away). Units: m, rad.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from planbench.errors import PlanbenchError, RobotFileError, UnknownNameError
from planbench.files.inputs import MAX_TEXT_BYTES, InputFileError, read_text
from planbench.robot import CONTINUOUS_RANGE, Robot, RobotSettings, example_robot_data_dir, link_of

__all__ = [
    "ALWAYS_FRACTION",
    "DEFAULT_SAMPLES",
    "DisabledPair",
    "PlanCheck",
    "RobotProposal",
    "plan_check",
    "propose",
    "settings_text",
]

DEFAULT_SAMPLES = 10000
"""Random configurations sampled for the ``always`` and ``never`` verdicts (MoveIt's setup assistant's
default; about 2 s on a 6-7 joint arm with mesh geometry, since a pair that has been seen both
colliding and free is no longer checked)."""
ALWAYS_FRACTION = 0.95
"""A pair in collision in at least this fraction of the samples is ``always`` in collision (MoveIt's
default)."""
REASONS = ("adjacent", "always", "default", "never")
MOVABLE = ("revolute", "continuous", "prismatic")
TOOL_WORDS = ("tool", "flange", "end_effector", "eef", "ee")
PLAN_CHECK_TIME = 5.0  # [s] RRT-Connect's time limit in plan_check
PLAN_CHECK_DISTANCE = 1.0  # [rad or m] least joint-space distance of plan_check's goal from home


@dataclass(frozen=True)
class _Joint:
    name: str
    type: str
    parent: str
    child: str
    lower: float
    upper: float


@dataclass(frozen=True)
class _Urdf:
    name: str
    joints: tuple[_Joint, ...]
    links: tuple[str, ...]

    def parent_joint(self, link: str) -> _Joint | None:
        return next((j for j in self.joints if j.child == link), None)

    def chain(self, link: str) -> list[_Joint]:
        """The joints from the root down to ``link``."""
        out = []
        j = self.parent_joint(link)
        while j is not None:
            out.append(j)
            j = self.parent_joint(j.parent)
        return out[::-1]


@dataclass(frozen=True)
class DisabledPair:
    """A link pair not checked for self-collision, and why (one of :data:`REASONS`); ``fraction``:
    the share of the random configurations in which it collided."""

    a: str
    b: str
    reason: str
    fraction: float = math.nan


@dataclass(frozen=True)
class RobotProposal:
    """What :func:`propose` found: the settings, and how it got them."""

    settings: RobotSettings
    disabled: tuple[DisabledPair, ...]
    kept: tuple[tuple[str, str], ...]
    """Link pairs still checked for self-collision."""
    default_kept: tuple[tuple[str, str], ...]
    """Of ``kept``, the pairs touching at the default configuration that MoveIt would disable."""
    srdf_pairs: int
    """Link pairs the SRDF already disables."""
    continuous: tuple[str, ...]
    home_source: str
    ee_source: str
    samples: int
    seed: int


def _input_path(path: str | Path) -> Path:
    """``path`` from the working folder, else in example-robot-data's robots/ folder; as given
    (for the error that names it) when in neither."""
    given = Path(path).expanduser()
    if given.exists():
        return given.resolve()
    if given.is_absolute():
        return given
    inside = example_robot_data_dir() / "robots" / given
    return inside if inside.exists() else given.absolute()


def _read_robot_xml(path: Path, kind: str) -> tuple[ET.Element, str]:
    """The root ``<robot>`` element of a URDF or SRDF (``kind``) and its text; a named error for a
    file that cannot be read, is not XML or has another root."""
    article = "an" if kind == "SRDF" else "a"
    try:
        text = read_text(path, MAX_TEXT_BYTES)
    except InputFileError as exc:
        raise RobotFileError(path, f"{kind}: {exc.problem}") from None
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise RobotFileError(path, f"not {article} {kind}: not XML ({exc})") from None
    if root.tag != "robot":
        raise RobotFileError(path, f"not {article} {kind}: its root element is <{root.tag}>, not <robot>")
    return root, text


def _read_urdf(path: Path) -> tuple[_Urdf, str]:
    root, text = _read_robot_xml(path, "URDF")
    links = tuple(str(link.get("name")) for link in root.findall("link"))
    joints = []
    for j in root.findall("joint"):
        parent, child, limit = j.find("parent"), j.find("child"), j.find("limit")
        kind = str(j.get("type"))
        if parent is None or child is None:
            raise RobotFileError(path, f"joint {j.get('name')!r} has no <parent> or <child>")
        if kind in ("floating", "planar"):
            raise RobotFileError(path, f"joint {j.get('name')!r} is {kind}: planbench plans fixed-base arms")
        lo, hi = -math.inf, math.inf
        if kind == "continuous":
            lo, hi = CONTINUOUS_RANGE
        elif kind in MOVABLE and limit is not None:
            lo, hi = float(limit.get("lower", "0")), float(limit.get("upper", "0"))
        joints.append(_Joint(str(j.get("name")), kind, str(parent.get("link")), str(child.get("link")), lo, hi))
    if not joints or not any(j.type in MOVABLE for j in joints):
        raise RobotFileError(path, "not a robot arm: the URDF has no revolute, continuous or prismatic joint")
    return _Urdf(str(root.get("name", path.stem)), tuple(joints), links), text


def _read_srdf(path: Path) -> ET.Element:
    return _read_robot_xml(path, "SRDF")[0]


def _tool_frame(urdf: _Urdf, srdf: ET.Element | None) -> tuple[str, str]:
    """The proposed tool frame (a link) and why (module docstring)."""
    if srdf is not None:
        for ee in srdf.findall("end_effector"):
            if ee.get("parent_link") in urdf.links:
                return str(ee.get("parent_link")), "the SRDF's end_effector parent_link"
        for chain in srdf.iter("chain"):
            if chain.get("tip_link") in urdf.links:
                return str(chain.get("tip_link")), "the tip link of the SRDF group's chain"
    parents = {j.parent for j in urdf.joints}
    leaves = [link for link in urdf.links if link not in parents]

    def rank(item: tuple[int, str]) -> tuple[int, int, int]:
        order, link = item
        movable = sum(j.type in MOVABLE for j in urdf.chain(link))
        word = next((len(TOOL_WORDS) - k for k, w in enumerate(TOOL_WORDS) if w in link.lower()), 0)
        return movable, word, order

    _, best = max(enumerate(leaves), key=rank)
    return best, "the URDF's leaf link with the most movable joints above it"


def _default_value(lo: float, hi: float) -> float:
    """A joint's default value, as MoveIt's: 0 when inside its range, else the middle of it."""
    return 0.0 if lo <= 0.0 <= hi else 0.5 * (lo + hi)


def propose(
    urdf: str | Path,
    srdf: str | Path | None = None,
    *,
    name: str | None = None,
    ee_frame: str | None = None,
    fixed: Mapping[str, float | None] | None = None,
    samples: int = DEFAULT_SAMPLES,
    seed: int = 0,
) -> RobotProposal:
    """Propose the settings of the robot of ``urdf`` (module docstring). ``fixed``: joints to hold
    (a value [rad or m], or None for the default one) besides those off the tool frame's chain.

    Raises :class:`RobotFileError` for a file that cannot be used, :class:`UnknownNameError` for a
    frame or joint the URDF does not have.
    """
    if samples < 1:
        raise PlanbenchError(f"samples must be >= 1, got {samples}")
    urdf_path = _input_path(urdf)
    model, _ = _read_urdf(urdf_path)
    srdf_path = _input_path(srdf) if srdf is not None else None
    srdf_root = _read_srdf(srdf_path) if srdf_path is not None else None

    if ee_frame is not None:
        if ee_frame not in model.links:
            raise UnknownNameError(f"link of {urdf_path.name} (tool frame)", ee_frame, model.links)
        ee, ee_source = ee_frame, "asked for"
    else:
        ee, ee_source = _tool_frame(model, srdf_root)

    by_name = {j.name: j for j in model.joints}
    movable = [j for j in model.joints if j.type in MOVABLE]
    held: dict[str, float] = {}
    for jname, value in (fixed or {}).items():
        if jname not in by_name or by_name[jname].type not in MOVABLE:
            raise UnknownNameError(f"movable joint of {urdf_path.name}", jname, [j.name for j in movable])
        j = by_name[jname]
        held[jname] = _default_value(j.lower, j.upper) if value is None else float(value)
    chain = {j.name for j in model.chain(ee) if j.type in MOVABLE}
    for j in movable:
        if j.name not in chain and j.name not in held:
            held[j.name] = _default_value(j.lower, j.upper)
    planned = [j for j in movable if j.name not in held]
    if not planned:
        raise PlanbenchError(f"no joint left to plan: the chain to {ee!r} has no movable joint that is not held")
    continuous = tuple(j.name for j in planned if j.type == "continuous")

    settings = RobotSettings(
        name=name or model.name,
        urdf=urdf_path,
        srdf=srdf_path,
        ee_frame=ee,
        fixed_joints={k: held[k] for k in sorted(held, key=[j.name for j in movable].index)},
        position_limits={k: CONTINUOUS_RANGE for k in continuous},
        source=str(urdf_path),
    )
    robot = Robot(settings)
    disabled, kept, default_kept, srdf_pairs = _disabled_pairs(robot, model, samples, seed)
    settings = settings.replace(ignore_collision_pairs=tuple((p.a, p.b) for p in disabled))
    # Home is free of the "default" pairs too: they are disabled on the assumption that the default
    # configuration is valid, not because they cannot touch.
    strict = settings.replace(ignore_collision_pairs=tuple((p.a, p.b) for p in disabled if p.reason != "default"))
    home, home_source = _home(Robot(strict), srdf_root, samples, seed)
    home = np.clip(np.round(home, 6), robot.lower, robot.upper)  # 1 urad, as the generated sets round
    settings = settings.replace(home=tuple(float(x) for x in home))
    return RobotProposal(
        settings,
        tuple(disabled),
        tuple(kept),
        tuple(default_kept),
        srdf_pairs,
        continuous,
        home_source,
        ee_source,
        samples,
        seed,
    )


def _link_pairs(robot: Robot) -> dict[tuple[str, str], list[int]]:
    """Per link pair (sorted names) with collision geometry, the indices of its active
    geometry pairs in ``robot.collision_model``."""
    return _link_pairs_of(robot.collision_model)


def _link_pairs_of(geom: Any) -> dict[tuple[str, str], list[int]]:
    out: dict[tuple[str, str], list[int]] = {}
    for k, pair in enumerate(geom.collisionPairs):
        a = link_of(geom.geometryObjects[pair.first].name)
        b = link_of(geom.geometryObjects[pair.second].name)
        if a != b:
            out.setdefault((min(a, b), max(a, b)), []).append(k)
    return out


def _adjacent(model: _Urdf, with_geometry: set[str]) -> set[tuple[str, str]]:
    """Parent/child link pairs, a link without geometry skipped (module docstring)."""
    out = set()
    for link in with_geometry:
        j = model.parent_joint(link)
        while j is not None and j.parent not in with_geometry:
            j = model.parent_joint(j.parent)
        if j is not None:
            out.add((min(link, j.parent), max(link, j.parent)))
    return out


def _default_q(robot: Robot) -> np.ndarray:
    return np.array([_default_value(lo, hi) for lo, hi in zip(robot.lower, robot.upper, strict=True)])


def _samples(robot: Robot, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return robot.lower + rng.random((n, robot.nq)) * (robot.upper - robot.lower)  # type: ignore[no-any-return]


def _disabled_pairs(
    robot: Robot, model: _Urdf, samples: int, seed: int
) -> tuple[list[DisabledPair], list[tuple[str, str]], list[tuple[str, str]], int]:
    import pinocchio as pin

    from planbench.checking.collision import fresh_geometry_data

    geom = robot.collision_model
    pairs = _link_pairs(robot)
    every = pin.GeometryModel(geom)
    every.removeAllCollisionPairs()
    every.addAllCollisionPairs()
    srdf_pairs = len(set(_link_pairs_of(every)) - set(pairs))
    adjacent = _adjacent(model, {link_of(g.name) for g in geom.geometryObjects})
    data = robot.model.createData()
    gdata = fresh_geometry_data(geom)

    def colliding(q: np.ndarray, among: Sequence[tuple[str, str]]) -> set[tuple[str, str]]:
        pin.computeCollisions(robot.model, data, geom, gdata, q, False)
        return {lp for lp in among if any(gdata.collisionResults[k].isCollision() for k in pairs[lp])}

    decided: dict[tuple[str, str], DisabledPair] = {}
    for lp in sorted(pairs):
        if lp in adjacent:
            decided[lp] = DisabledPair(*lp, "adjacent")
    at_default = colliding(_default_q(robot), list(pairs))
    # The random configurations. A pair that has collided, and has been free in more than
    # (1 - ALWAYS_FRACTION) of the samples, is neither "always" nor "never": it is no longer
    # checked in the samples after (the verdicts are the same, the sampling much faster).
    undecided = [lp for lp in sorted(pairs) if lp not in decided]
    for k in range(len(geom.collisionPairs)):
        gdata.deactivateCollisionPair(k)
    for lp in undecided:
        for k in pairs[lp]:
            gdata.activateCollisionPair(k)
    counts = dict.fromkeys(undecided, 0)
    sometimes: list[tuple[str, str]] = []
    free_allowed = (1.0 - ALWAYS_FRACTION) * samples
    for i, q in enumerate(_samples(robot, samples, seed)):
        if not undecided:
            break
        for lp in colliding(q, undecided):
            counts[lp] += 1
        for lp in [lp for lp in undecided if counts[lp] and (i + 1 - counts[lp]) > free_allowed]:
            undecided.remove(lp)
            sometimes.append(lp)
            for k in pairs[lp]:
                gdata.deactivateCollisionPair(k)
    kept, default_kept = [], []
    for lp in sorted(counts):
        fraction = counts[lp] / samples
        if lp in undecided and fraction >= ALWAYS_FRACTION:
            decided[lp] = DisabledPair(*lp, "always", fraction)
        elif lp in at_default and counts[lp] == 0:
            decided[lp] = DisabledPair(*lp, "default")
        elif lp in undecided and counts[lp] == 0:
            decided[lp] = DisabledPair(*lp, "never", 0.0)
        else:
            kept.append(lp)
            if lp in at_default:
                default_kept.append(lp)
    disabled = sorted(decided.values(), key=lambda p: (REASONS.index(p.reason), p.a, p.b))
    return disabled, kept, default_kept, srdf_pairs


def _home(robot: Robot, srdf: ET.Element | None, samples: int, seed: int) -> tuple[np.ndarray, str]:
    from planbench.checking.collision import CollisionChecker
    from planbench.scene import Scene

    checker = CollisionChecker(robot, Scene((), "empty"))

    def free(q: np.ndarray) -> bool:
        return not robot.limit_violations(q) and not checker.in_collision(q)

    if srdf is not None:
        for state in srdf.findall("group_state"):
            values = {str(j.get("name")): j.get("value") for j in state.findall("joint")}
            if all(n in values for n in robot.joint_names):
                try:
                    q = np.array([float(str(values[n]).split()[0]) for n in robot.joint_names])
                except ValueError:
                    continue
                if free(q):
                    return q, f"the SRDF's group_state {state.get('name')!r}"
    middle = 0.5 * (robot.lower + robot.upper)
    if free(middle):
        return middle, "the middle of the joint ranges"
    if free(_default_q(robot)):
        return _default_q(robot), "the default configuration (every joint at 0, or mid-range)"
    qs = _samples(robot, samples, seed + 1)
    order = np.argsort(np.linalg.norm((qs - middle) / (robot.upper - robot.lower), axis=1))
    for i in order:
        if free(qs[i]):
            return qs[i], "the collision-free random configuration nearest the middle of the ranges"
    raise PlanbenchError(f"robot {robot.name!r}: no collision-free configuration among {samples} random ones")


def _path_text(path: Path, out_dir: Path) -> str:
    """How the settings file names ``path``: under example-robot-data's robots/ folder relative to
    it (as the shipped robots do), else relative to the settings file's folder."""
    try:
        return path.relative_to(example_robot_data_dir() / "robots").as_posix()
    except (ValueError, PlanbenchError):
        return Path(os.path.relpath(path, out_dir)).as_posix()


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _num(x: float) -> str:
    return repr(round(float(x), 6))


def settings_text(proposal: RobotProposal, out: str | Path) -> str:
    """The settings file of ``proposal`` (TOML with comments), paths written for a file at ``out``."""
    s = proposal.settings
    out_dir = Path(out).expanduser().resolve().parent
    robot = Robot(s)
    lines = [
        f"# {s.name} ({robot.nq} planned joints), written by `planbench robot add` from {Path(s.urdf).name}.",
        "# Units: metres, radians, seconds. Format: see planbench/robot.py (RobotSettings).",
        "# Relative paths are looked up beside this file first, then in example-robot-data's robots/ folder.",
        f"name = {_toml_str(s.name)}",
        f"description = {_toml_str(f'{s.name}, from {Path(s.urdf).name} (planbench robot add)')}",
        f"urdf = {_toml_str(_path_text(Path(s.urdf), out_dir))}",
    ]
    if s.srdf is not None:
        lines.append(f"srdf = {_toml_str(_path_text(Path(s.srdf), out_dir))}")
    lines += [
        f"# The tool frame: {proposal.ee_source}.",
        f"ee_frame = {_toml_str(s.ee_frame)}",
        f"# Home: {proposal.home_source}; collision-free.",
        f"# Planned joints: {', '.join(robot.joint_names)}.",
        "home = [" + ", ".join(_num(x) for x in (s.home or ())) + "]",
        "",
        "# Link pairs never checked for self-collision, as MoveIt's setup assistant finds them: adjacent",
        f"# (parent and child), always (touching in at least {ALWAYS_FRACTION:.0%} of {proposal.samples} random "
        f"configurations, seed {proposal.seed}),",
        "# default (touching with every joint at 0, or mid-range where 0 is outside it, and in none of the random",
        "# configurations), never (touching in none of the random configurations).",
    ]
    if proposal.srdf_pairs:
        lines.append(f"# The SRDF disables {proposal.srdf_pairs} more link pairs.")
    lines.append(f"# Still checked: {len(proposal.kept)} link pairs.")
    if proposal.default_kept:
        lines.append("# Touching at the default configuration and in some random configurations too, so still checked")
        lines.append("# (MoveIt would disable them): " + ", ".join(f"{a}-{b}" for a, b in proposal.default_kept) + ".")
    lines.append("ignore_collision_pairs = [")
    for reason in REASONS:
        group = [p for p in proposal.disabled if p.reason == reason]
        if group:
            lines.append(f"  # {reason} ({len(group)})")
            lines += [f"  [{_toml_str(p.a)}, {_toml_str(p.b)}]," for p in group]
    lines.append("]")
    if s.fixed_joints:
        lines += [
            "",
            "[fixed_joints]",
            "# Not on the chain to the tool frame (or asked to be held): held here [rad or m].",
        ]
        lines += [f"{_toml_str(k)} = {_num(v)}" for k, v in s.fixed_joints.items()]
    if s.position_limits:
        lines += [
            "",
            "[position_limits]",
            "# Continuous joints, planned over one full turn [rad] (planbench's default, CONTINUOUS_RANGE);",
            "# widen a range here to let the planners turn a joint further.",
        ]
        lines += [f"{_toml_str(k)} = [{lo!r}, {hi!r}]" for k, (lo, hi) in s.position_limits.items()]
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class PlanCheck:
    """The outcome of :func:`plan_check`."""

    planner: str
    success: bool
    planning_time: float
    """[s]"""
    distance: float
    """[rad or m] joint-space distance from home to the goal"""
    message: str


def plan_check(robot_or_path: Robot | str | Path, seed: int = 0, planner: str = "ompl-rrtconnect") -> PlanCheck:
    """Plan from home to a random collision-free configuration at least
    :data:`PLAN_CHECK_DISTANCE` away, in an empty scene, with ``planner`` (seeded); the path is
    checked by :func:`planbench.evaluate`."""
    from planbench.checking.collision import CollisionChecker
    from planbench.harness import plan
    from planbench.problem import Problem
    from planbench.robot import load_robot
    from planbench.scene import Scene
    from planbench.validate import evaluate

    robot = robot_or_path if isinstance(robot_or_path, Robot) else load_robot(robot_or_path)
    scene = Scene((), "empty")
    checker = CollisionChecker(robot, scene)
    home = np.asarray(robot.home)
    goal = None
    for q in _samples(robot, 1000, seed):
        if np.linalg.norm(q - home) >= PLAN_CHECK_DISTANCE and not checker.in_collision(q):
            goal = q
            break
    if goal is None:
        return PlanCheck(planner, False, math.nan, math.nan, "no collision-free goal among 1000 random configurations")
    problem = Problem.create(robot, scene, home, goal, id=f"{robot.name}:plan-check")
    result = plan(problem, planner, seed=seed, time_limit=PLAN_CHECK_TIME)
    ev = evaluate(problem, result)
    return PlanCheck(
        planner,
        bool(ev.success),
        float(result.planning_time),
        float(np.linalg.norm(goal - home)),
        "" if ev.success else str(ev.failure),
    )


def describe(proposal: RobotProposal) -> Sequence[str]:
    """Lines that say what :func:`propose` found (for the command's output)."""
    s = proposal.settings
    counts = {r: sum(p.reason == r for p in proposal.disabled) for r in REASONS}
    out = [
        f"tool frame {s.ee_frame} ({proposal.ee_source})",
        f"home {list(s.home or ())} ({proposal.home_source})",
        "collision pairs disabled: "
        + ", ".join(f"{n} {r}" for r, n in counts.items())
        + f" (from {proposal.samples} random configurations, seed {proposal.seed}); "
        + f"{len(proposal.kept)} link pairs still checked"
        + (f"; the SRDF disables {proposal.srdf_pairs} more" if proposal.srdf_pairs else ""),
    ]
    if proposal.default_kept:
        out.append(
            "still checked though touching at the default configuration (they touch in some random ones too; "
            "MoveIt would disable them): " + ", ".join(f"{a}-{b}" for a, b in proposal.default_kept)
        )
    if proposal.continuous:
        lo, hi = CONTINUOUS_RANGE
        out.append(f"continuous joints {', '.join(proposal.continuous)}: range [{lo:.6g}, {hi:.6g}] rad")
    if s.fixed_joints:
        out.append("held fixed: " + ", ".join(f"{k} = {v:g}" for k, v in s.fixed_joints.items()))
    return out

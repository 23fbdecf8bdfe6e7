"""Problem sets by name: ``load_problems("mbm:box")``, ``"mbm:box/0001"``, ``"mbm:*"``, files.

Selectors:

- ``mbm`` or ``mbm:*``: all 700 MotionBenchMaker Panda problems (7 families x 100);
- ``mbm:<family>``: one family; ``mbm:<family>/0007``: one problem;
- ``mbm:<family>/0001-0020`` or ``mbm:*/0021-0100``: an index range (inclusive);
- ``gen`` or ``gen:*``: planbench's own generated problems (``planbench/data/gen``, see
  :mod:`planbench.problems.generators`); ``gen:<robot>_<family>/0001-0003``, ``gen:ur5_*``, ``gen:*_shelf``;
- ``examples`` or ``examples:<name>``: the shipped example problems (``planbench/data/examples``),
  e.g. ``examples:depth_camera_table``, a depth-camera point cloud (:mod:`planbench.reactive.depth_example`);
- a path to a problem JSON file, or to a folder of them;
- any ``mbm:`` or ``gen:`` selector with ``:bare`` after it (``gen:ur5_table_clutter/0002:bare``):
  the same problems with their clutter removed, every obstacle named ``object*`` (a table's
  objects; the table, its legs, shelves and the floor stay). Their ids and scene names end in
  ``:bare`` / ``-bare``. The ``dynamic`` scenario set uses them, so that its moving obstacles are the challenge.

The MotionBenchMaker data ships inside planbench (``planbench/data/mbm``, with its README as
attribution and licence notice: Apache-2.0 via VAMP, generated with BSD-3-Clause MotionBenchMaker).
"""

from __future__ import annotations

import collections
import dataclasses
import fnmatch
import functools
import json
import re
from importlib import resources
from pathlib import Path
from typing import Any

from planbench.errors import DuplicateProblemError, PlanbenchError, UnknownNameError
from planbench.problem import Goal, Pose, Problem, Tolerances
from planbench.robot import load_robot
from planbench.scene import Scene

__all__ = ["load_problem", "load_problems", "mbm_families", "problem_sets", "shipped_problems", "shipped_sets"]

_RANGE = re.compile(r"^(\d+)(?:-(\d+))?$")


def problem_sets() -> dict[str, str]:
    """Names of the built-in problem sets and what they are."""
    return {
        "mbm": "MotionBenchMaker Panda set (Chamzas et al. 2022), 7 families x 100 problems: "
        + ", ".join(mbm_families()),
        "gen": "planbench's own generated scenes (planbench.problems.generators), 25 problems per set: "
        + ", ".join(shipped_sets()),
        "examples": "shipped example problems: " + ", ".join(example_names()),
    }


def _mbm_dir() -> Any:
    return resources.files("planbench") / "data" / "mbm"


@functools.cache
def _manifest() -> dict[str, Any]:
    return json.loads((_mbm_dir() / "manifest.json").read_text())  # type: ignore[no-any-return]


def mbm_families() -> list[str]:
    return sorted(_manifest()["families"])


@functools.cache
def _family_data(family: str) -> dict[str, Any]:
    entry = _manifest()["families"][family]
    return json.loads((_mbm_dir() / entry["file"]).read_text())  # type: ignore[no-any-return]


def _mbm_problem(d: dict[str, Any], family: dict[str, Any]) -> Problem:
    fingers = dict(zip(family["finger_joint_names"], d["finger_positions"], strict=True))
    robot = load_robot(family["robot"], fixed_joints=fingers)
    if list(robot.joint_names) != family["joint_names"]:
        raise PlanbenchError(f"MotionBenchMaker joints {family['joint_names']} differ from robot {robot.joint_names}")
    scene = Scene.from_dict({"name": d["id"], "obstacles": d["obstacles"]}, f"mbm:{d['id']}")
    frame = robot.settings.ee_frame
    if frame in d["goal_ee_pose"]:
        g = d["goal_ee_pose"][frame]
        pose = Pose.from_xyzw(g["position"], g["orientation_xyzw"], frame)
    else:
        M = robot.frame_pose(d["goal"])
        pose = Pose(M.translation.copy(), M.rotation.copy(), frame)
    return Problem(
        robot,
        scene,
        d["start"],
        Goal(pose, d["goal"]),
        Tolerances(),
        f"mbm:{d['id']}",
        {"set": "mbm", "family": family["family"], "index": d["index"]},
    )


def load_problems(selector: str | Path) -> list[Problem]:
    """Problems named by ``selector`` (see the module docstring), in a stable order."""
    text = str(selector)
    if text.endswith(BARE) and text.partition(":")[0] in ("mbm", "gen"):
        return [_bare(p) for p in load_problems(text.removesuffix(BARE))]
    if text == "mbm" or text.startswith("mbm:"):
        return _load_mbm(text.partition(":")[2] or "*")
    if text == "gen" or text.startswith("gen:"):
        return _load_gen(text.partition(":")[2] or "*")
    if text == "examples" or text.startswith("examples:"):
        return _load_examples(text.partition(":")[2] or "*")
    path = Path(text)
    if path.is_dir():
        files = sorted(path.glob("*.json"))
        if not files:
            raise PlanbenchError(f"{path}: folder holds no problem .json files")
        return _unique_ids([(Problem.load(f), str(f)) for f in files])
    if path.is_file() or (path.exists() and text.endswith(".json")):  # a FIFO or a device: named by Problem.load
        return [Problem.load(path)]
    names = ["mbm", "mbm:*", *(f"mbm:{f}" for f in mbm_families()), "gen:*", *(f"gen:{s}" for s in shipped_sets())]
    names += ["examples", *(f"examples:{n}" for n in example_names())]
    raise UnknownNameError("problem set or file", text, names)


BARE = ":bare"
"""The selector suffix that removes a problem's clutter (module docstring)."""


def _bare(problem: Problem) -> Problem:
    kept = tuple(o for o in problem.scene.obstacles if not o.name.startswith("object"))
    scene = Scene(kept, problem.scene.name + "-bare")
    return dataclasses.replace(problem, scene=scene, id=problem.id + BARE)


_ONE: collections.OrderedDict[str, Problem] = collections.OrderedDict()
LOADED_PROBLEMS_KEPT = 8
"""Problems :func:`load_problem` keeps loaded, the most recently used. Bounded because what is
built for a problem is cached on it (collision and certified checkers with their convex hulls,
tens of MB on a large scene): a worker that kept every problem of a 760-problem suite grew past
its 4 GiB address-space limit."""


def load_problem(ref: str) -> Problem:
    """The one problem a reference names (``"mbm:box/0001"``, a .json file), loaded once while it
    is among the :data:`LOADED_PROBLEMS_KEPT` last used: benchmark workers and validators load each
    run's problem by reference."""
    return load_one(_ONE, ref, load_problems, "problem")


def load_one(kept: collections.OrderedDict[str, Any], ref: str, load: Any, what: str) -> Any:
    """The one item ``load(ref)`` gives, from ``kept`` (the :data:`LOADED_PROBLEMS_KEPT` last
    used, least recent first) or loaded into it; :class:`PlanbenchError` when ``ref`` names
    another number of items."""
    item = kept.get(ref)
    if item is None:
        found = load(ref)
        if len(found) != 1:
            raise PlanbenchError(f"{what} reference {ref!r} names {len(found)} {what}s, not one")
        item = kept[ref] = found[0]
        while len(kept) > LOADED_PROBLEMS_KEPT:
            kept.popitem(last=False)
    kept.move_to_end(ref)
    return item


def _unique_ids(loaded: list[tuple[Problem, str]]) -> list[Problem]:
    """The problems, or :class:`DuplicateProblemError` naming two files that share an id (results
    and tables are keyed by the id, so they would be mixed up)."""
    seen: dict[str, str] = {}
    for problem, source in loaded:
        first = seen.setdefault(problem.id, source)
        if first != source:
            raise DuplicateProblemError(problem.id, first, source)
    return [problem for problem, _ in loaded]


def _examples_dir() -> Path:
    return Path(str(resources.files("planbench") / "data" / "examples"))


def example_names() -> list[str]:
    """Names of the shipped example problems (``examples:<name>``)."""
    return sorted(p.stem for p in _examples_dir().glob("*.json"))


def _load_examples(pattern: str) -> list[Problem]:
    chosen = [n for n in example_names() if fnmatch.fnmatchcase(n, pattern)]
    if not chosen:
        raise UnknownNameError("example problem", pattern, example_names())
    return [Problem.load(_examples_dir() / f"{n}.json") for n in chosen]


def _load_mbm(rest: str) -> list[Problem]:
    fam_part, _, idx_part = rest.partition("/")
    families = mbm_families()
    if fam_part in ("*", ""):
        chosen = families
    elif fam_part in families:
        chosen = [fam_part]
    else:
        raise UnknownNameError("MotionBenchMaker family", fam_part, families)
    lo, hi = 1, 10**9
    if idx_part:
        m = _RANGE.match(idx_part)
        if not m:
            raise PlanbenchError(f"bad problem index {idx_part!r}: use e.g. 0007 or 0001-0020")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) else lo
    out: list[Problem] = []
    for fam in chosen:
        data = _family_data(fam)
        out.extend(_mbm_problem(p, data) for p in data["problems"] if lo <= p["index"] <= hi)
    if not out:
        raise PlanbenchError(f"no MotionBenchMaker problem matches 'mbm:{rest}' (indices run 0001-0100)")
    return out


def _load_gen(rest: str) -> list[Problem]:
    pattern, _, idx_part = rest.partition("/")
    names = shipped_sets()
    chosen = [n for n in names if fnmatch.fnmatchcase(n, pattern or "*")]
    if not chosen:
        raise UnknownNameError("generated problem set (<robot>_<family>)", pattern, names)
    lo, hi = 1, 10**9
    if idx_part:
        m = _RANGE.match(idx_part)
        if not m:
            raise PlanbenchError(f"bad problem index {idx_part!r}: use e.g. 0007 or 0001-0020")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) else lo
    out = [p for name in chosen for p in shipped_problems(name, lo, hi)]
    if not out:
        raise PlanbenchError(f"no generated problem matches 'gen:{rest}' (indices run 0001-0025)")
    return out


# --- planbench's own generated set (written by planbench.problems.generators) --------------------------

GEN_SEED = 0
"""The seed of the shipped generated set; problems of other seeds are named ``gen-s<seed>:``."""


def _gen_dir() -> Any:
    return resources.files("planbench") / "data" / "gen"


@functools.cache
def _gen_manifest() -> dict[str, Any]:
    return json.loads((_gen_dir() / "manifest.json").read_text())  # type: ignore[no-any-return]


def shipped_sets() -> list[str]:
    """Names of the shipped generated sets, ``<robot>_<family>``."""
    return sorted(_gen_manifest()["sets"])


@functools.cache
def _set_data(name: str) -> dict[str, Any]:
    return json.loads((_gen_dir() / _gen_manifest()["sets"][name]["file"]).read_text())  # type: ignore[no-any-return]


def problem_from_record(record: dict[str, Any], header: dict[str, Any]) -> Problem:
    """A problem of a ``planbench-gen/1`` file (the goal pose is the end effector's at the goal)."""
    robot = load_robot(header["robot"])
    if list(robot.joint_names) != header["joint_names"]:
        raise PlanbenchError(f"generated set {header['name']}: joints {header['joint_names']} differ from the robot's")
    pid = f"gen:{record['id']}" if header["seed"] == GEN_SEED else f"gen-s{header['seed']}:{record['id']}"
    scene = Scene.from_dict({"name": pid, "obstacles": record["obstacles"]}, pid)
    metadata = {
        "set": "gen",
        "family": header["family"],
        "robot": header["robot"],
        "index": record["index"],
        "seed": header["seed"],
        "generator": header["generator"],
        "attempts": record["attempts"],
        **record["params"],
    }
    return Problem.create(robot, scene, record["start"], record["goal"], id=pid, metadata=metadata)


def shipped_problems(name: str, lo: int = 1, hi: int = 10**9) -> list[Problem]:
    """Problems ``lo``..``hi`` (indices, inclusive) of the shipped set ``name``."""
    if name not in shipped_sets():
        raise UnknownNameError("generated problem set", name, shipped_sets())
    data = _set_data(name)
    return [problem_from_record(rec, data) for rec in data["problems"] if lo <= rec["index"] <= hi]

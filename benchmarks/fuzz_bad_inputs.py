"""Fuzz planbench's command line with malformed input, and say which inputs are not refused cleanly.

Every case runs one CLI command in a fresh process (``python -m planbench.cli.main ...``, or
``python -m planbench.problems.generate``) with a wall-clock timeout and an address-space limit, and is
classified:

- ``good``: exit code 2 and a one-line named error (``planbench: error: ...`` or argparse's
  ``error:``), no traceback;
- ``ran``: exit code 0 or 1 (the input was accepted; listed so that a person can judge it);
- ``TRACEBACK``, ``HANG`` (past the timeout), ``EXIT`` (another exit code or a signal),
  ``MEMORY`` (a peak resident memory past ``--memory-flag`` MiB, whatever the exit code).

The inputs are written into a scratch folder first (problem, scene, scenario, suite, robot,
point-cloud and results files, a FIFO, links to /dev/zero); nothing outside it is touched.

Usage::

    python benchmarks/fuzz_bad_inputs.py [--jobs 2] [--timeout 60] [--only TEXT] [--json out.json]

Exit code 0 when every case is ``good`` or ``ran``, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sqlite3
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
AS_LIMIT = 8 << 30  # address space of a case's process [B]: a runaway allocation ends as MemoryError


@dataclass
class Case:
    name: str
    args: list[str]
    module: str = "planbench.cli.main"
    expect: str = "refused"  # "refused": exit 2 expected; "any": exit 0/1 is fine too
    result: dict[str, Any] = field(default_factory=dict)


# --- the input files ------------------------------------------------------------------------------


def _problem_dict() -> dict[str, Any]:
    import planbench

    d = planbench.load_problems("mbm:box/0001")[0].to_dict()
    d["id"] = "fuzz"
    return d


def _write_npz_bomb(path: Path, n_points: int) -> None:
    """A .npz whose 'points' array is ``n_points`` x 3 float64 zeros, deflated (about 1000:1),
    written in chunks (the array is never held in memory)."""
    header = {"descr": "<f8", "fortran_order": False, "shape": (n_points, 3)}
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as z:
        with z.open("points.npy", "w", force_zip64=True) as f:
            np.lib.format.write_array_header_1_0(f, header)  # type: ignore[attr-defined]
            chunk = bytes(1 << 24)
            left = n_points * 24
            while left:
                f.write(chunk[: min(left, len(chunk))])
                left -= min(left, len(chunk))


def _npz_with_header(path: Path, shape: tuple[int, ...], data: bytes, descr: str = "<f8") -> None:
    """A .npz whose 'points' header claims ``shape`` but holds ``data``."""
    import io

    buf = io.BytesIO()
    header = {"descr": descr, "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(buf, header)  # type: ignore[attr-defined]
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("points.npy", buf.getvalue() + data)


def _ply_ascii(path: Path, claimed: int, rows: list[str]) -> None:
    props = "property float x\nproperty float y\nproperty float z\n"
    head = f"ply\nformat ascii 1.0\nelement vertex {claimed}\n{props}end_header\n"
    path.write_text(head + "".join(r + "\n" for r in rows))


def _ply_binary(path: Path, claimed: int, points: np.ndarray) -> None:
    head = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {claimed}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    ).encode()
    path.write_bytes(head + np.asarray(points, "<f4").tobytes())


def _results_db(path: Path) -> None:
    from planbench.bench.db import ResultsDB
    from planbench.bench.records import failure_record

    with ResultsDB(path) as db:
        db.put_suite("s", {"planners": []}, "{}")
        for i in range(3):
            rec = failure_record("timeout", "killed")
            rec["path"] = np.random.default_rng(i).normal(size=(20, 7))
            db.add_run(
                dict(
                    suite="s",
                    problem=f"mbm:box/{i + 1:04d}",
                    family="box",
                    planner="p",
                    seed=0,
                    planner_name="p",
                    settings={},
                ),
                rec,
            )


def _db_variant(good: Path, out: Path, sql: str) -> None:
    shutil.copy(good, out)
    conn = sqlite3.connect(out)
    conn.executescript(sql)
    conn.commit()
    conn.close()


def make_inputs(w: Path) -> None:
    """Every file the cases name, in ``w``."""
    P = _problem_dict()

    def jdump(name: str, obj: Any) -> None:
        (w / name).write_text(json.dumps(obj))

    def prob(name: str, **changes: Any) -> None:
        jdump(name, {**P, **changes})

    def with_obstacle(name: str, obstacle: dict[str, Any]) -> None:
        scene = dict(P["scene"])
        scene["obstacles"] = list(scene["obstacles"]) + [obstacle]
        prob(name, scene=scene)

    # problem files: bytes
    (w / "empty.json").write_bytes(b"")
    (w / "garbage.json").write_bytes(os.urandom(4096))
    (w / "truncated.json").write_text(json.dumps(P)[:500])
    (w / "array.json").write_text("[1, 2, 3]")
    (w / "null.json").write_text("null")
    (w / "string.json").write_text('"hello"')
    (w / "deep.json").write_text("[" * 200_000 + "]" * 200_000)
    (w / "deep_obj.json").write_text('{"a":' * 100_000 + "1" + "}" * 100_000)
    (w / "utf16.json").write_bytes(json.dumps(P).encode("utf-16"))
    (w / "latin1.json").write_bytes(json.dumps({**P, "id": "caf\u00e9"}).encode("latin-1"))
    (w / "bigint.json").write_text(json.dumps(P).replace('"start": [', '"start": [' + "9" * 5000 + ", ", 1))
    (w / "huge.json").write_text('{"pad": "' + "x" * (300 << 20) + '"}')
    # problem files: values
    nq = len(P["start"])
    q = P["start"]
    prob("nan_start.json", start=[float("nan")] * nq)
    prob("inf_goal.json", goal={"q": [float("inf")] * nq})
    prob("huge_start.json", start=[1e308] * nq)
    (w / "overflow_start.json").write_text(json.dumps(P).replace('"start": [', '"start": [1e999, ', 1))
    prob("short_start.json", start=q[:3])
    prob("long_start.json", start=q + [0.0] * 100)
    prob("empty_start.json", start=[])
    prob("goal_out_of_reach.json", goal={"pose": {"position": [5.0, 0.0, 0.5], "orientation_xyzw": [0, 0, 0, 1]}})
    prob("goal_nan_pose.json", goal={"pose": {"position": [float("nan"), 0, 0.5], "orientation_xyzw": [0, 0, 0, 1]}})
    prob("goal_zero_quat.json", goal={"pose": {"position": [0.3, 0, 0.5], "orientation_xyzw": [0, 0, 0, 0]}})
    prob("goal_q_limits.json", goal={"q": [10.0] * nq})
    prob("start_limits.json", start=[10.0] * nq)
    prob(
        "goal_frame.json", goal={"pose": {"position": [0.3, 0, 0.5], "orientation_xyzw": [0, 0, 0, 1], "frame": "nope"}}
    )
    prob("neg_tol.json", tolerances={"position": -1.0})
    prob("zero_tol.json", tolerances={"position": 0})
    prob("nan_tol.json", tolerances={"joint": float("nan")})
    prob("huge_tol.json", tolerances={"position": 1e308, "orientation": 1e308, "joint": 1e308})
    prob("empty_id.json", id="")
    prob("long_id.json", id="x" * 100_000)
    prob("ctrl_id.json", id="a\nb\x00c\x1b[31m")
    prob("fmt.json", format="planbench-problem/99")
    prob("no_goal.json", goal={})
    prob("goal_list.json", goal=[1, 2])
    prob("metadata_deep.json", metadata={"a": [[[[1]]]]})
    prob("robot_missing_toml.json", robot="missing_robot.toml")
    prob("robot_garbage_toml.json", robot="garbage.toml")
    prob("robot_dir.json", robot="adir.toml")
    prob("robot_fifo.json", robot="fifo.toml")
    prob("robot_devzero.json", robot="devzero.toml")
    prob("robot_dict_bad_urdf.json", robot={"name": "r", "urdf": "garbage.urdf", "ee_frame": "x"})
    prob("robot_dict_dir_urdf.json", robot={"name": "r", "urdf": "adir", "ee_frame": "x"})
    prob("robot_dict_fifo_urdf.json", robot={"name": "r", "urdf": "fifo.urdf", "ee_frame": "x"})
    prob("robot_dict_devzero_urdf.json", robot={"name": "r", "urdf": "devzero.urdf", "ee_frame": "x"})
    prob("robot_dict_empty_urdf.json", robot={"name": "r", "urdf": "empty.urdf", "ee_frame": "x"})
    prob("robot_dict_nocoll_urdf.json", robot={"name": "r", "urdf": "nocollision.urdf", "ee_frame": "link"})
    prob("robot_dict_types.json", robot={"name": "r", "urdf": 5, "ee_frame": ["x"]})
    prob("robot_toml_types.json", robot="types.toml")
    prob("override_unknown_joint.json", robot_overrides={"fixed_joints": {"nope": 0.1}})
    prob("override_nan.json", robot_overrides={"fixed_joints": {"panda_finger_joint1": float("nan")}})
    prob("override_limits_inverted.json", robot_overrides={"position_limits": {"panda_joint1": [1.0, -1.0]}})
    prob("override_vel_neg.json", robot_overrides={"velocity_limits": {"panda_joint1": -1.0}})
    prob("override_vel_zero.json", robot_overrides={"velocity_limits": {"panda_joint1": 0.0}})
    prob("scene_missing.json", scene="missing_scene.json")
    prob("scene_dir.json", scene="adir")
    prob("scene_fifo.json", scene="fifo.json")
    prob("scene_devzero.json", scene="devzero.json")
    prob("scene_garbage.json", scene="garbage.json")
    prob("scene_self.json", scene="scene_self.json")
    prob("scene_obstacles_dict.json", scene={"obstacles": {"a": 1}})
    base_box = {"name": "b", "type": "box", "size": [0.1, 0.1, 0.1], "position": [0.5, 0.5, 0.5]}
    with_obstacle("box_nan.json", {**base_box, "position": [float("nan"), 0, 0]})
    with_obstacle("box_inf_size.json", {**base_box, "size": [float("inf"), 1, 1]})
    with_obstacle("box_huge.json", {**base_box, "size": [1e6, 1e6, 1e6]})
    with_obstacle("box_far.json", {**base_box, "position": [1e9, 1e9, 1e9]})
    with_obstacle("box_neg.json", {**base_box, "size": [-1, 1, 1]})
    with_obstacle("box_str_size.json", {**base_box, "size": "abc"})
    with_obstacle("box_int_size.json", {**base_box, "size": 5})
    with_obstacle("box_bad_quat.json", {**base_box, "orientation_xyzw": [0, 0, 0, 2]})
    with_obstacle("box_nested.json", {**base_box, "size": [[1], [2], [3]]})
    with_obstacle("sphere_zero.json", {"name": "s", "type": "sphere", "radius": 0})
    with_obstacle("sphere_str.json", {"name": "s", "type": "sphere", "radius": "big"})
    with_obstacle("sphere_list.json", {"name": "s", "type": "sphere", "radius": [1]})
    with_obstacle("cyl_nan.json", {"name": "c", "type": "cylinder", "radius": 0.1, "length": float("nan")})
    with_obstacle("unknown_type.json", {"name": "u", "type": "torus"})
    with_obstacle("dup_name.json", {**base_box, "name": P["scene"]["obstacles"][0]["name"]})
    with_obstacle("mesh_missing.json", {"name": "m", "type": "mesh", "path": "missing.stl"})
    with_obstacle("mesh_garbage.json", {"name": "m", "type": "mesh", "path": "garbage.stl"})
    with_obstacle("mesh_empty.json", {"name": "m", "type": "mesh", "path": "empty.stl"})
    with_obstacle("mesh_dir.json", {"name": "m", "type": "mesh", "path": "adir.stl"})
    with_obstacle("mesh_fifo.json", {"name": "m", "type": "mesh", "path": "fifo.stl"})
    with_obstacle("mesh_devzero.json", {"name": "m", "type": "mesh", "path": "devzero.stl"})
    with_obstacle("mesh_scale_nan.json", {"name": "m", "type": "mesh", "path": "tiny.stl", "scale": [float("nan")] * 3})
    with_obstacle("mesh_scale_zero.json", {"name": "m", "type": "mesh", "path": "tiny.stl", "scale": [0, 0, 0]})
    # point clouds
    pc = {"name": "cloud", "type": "pointcloud", "radius": 0.005}
    for fname in (
        "bomb.npz",
        "npz_claims_huge.npz",
        "npz_claims_neg.npz",
        "npz_garbage.npz",
        "npz_empty.npz",
        "npz_nan.npz",
        "npz_inf.npz",
        "npz_object.npz",
        "npz_complex.npz",
        "npz_bool.npz",
        "npz_4col.npz",
        "npz_1d.npz",
        "npz_0d.npz",
        "npz_zero_points.npz",
        "npz_no_points.npz",
        "npz_far_apart.npz",
        "npz_far_origin.npz",
        "single.npy.npz",
        "ply_claims_huge_ascii.ply",
        "ply_claims_huge_binary.ply",
        "ply_claims_neg.ply",
        "ply_garbage.ply",
        "ply_empty.ply",
        "ply_header_only.ply",
        "ply_nan.ply",
        "ply_faces_only.ply",
        "fifo.npz",
        "devzero.ply",
        "adir.npz",
        "cloud.xyz",
    ):
        with_obstacle(f"pc_{fname.replace('.', '_')}.json", {**pc, "path": fname})
    with_obstacle("pc_tiny_radius.json", {**pc, "path": "good.npz", "radius": 1e-12})
    with_obstacle("pc_huge_radius.json", {**pc, "path": "good.npz", "radius": 5.0})
    with_obstacle("pc_nan_radius.json", {**pc, "path": "good.npz", "radius": float("nan")})
    with_obstacle("pc_far_apart_small_radius.json", {**pc, "path": "npz_far_apart.npz", "radius": 0.004})
    with_obstacle("pc_good.json", {**pc, "path": "good.npz"})

    # supporting files
    (w / "adir").mkdir()
    for d in ("adir.toml", "adir.stl", "adir.npz", "adir.json"):
        (w / d).mkdir()
    os.mkfifo(w / "fifo")
    for name in ("fifo.json", "fifo.toml", "fifo.urdf", "fifo.stl", "fifo.npz", "fifo.db"):
        os.mkfifo(w / name)
    for name in ("devzero.json", "devzero.toml", "devzero.urdf", "devzero.stl", "devzero.ply", "devzero.db"):
        (w / name).symlink_to("/dev/zero")
    (w / "devnull.db").symlink_to("/dev/null")
    (w / "loop.json").symlink_to(w / "loop.json")
    (w / "garbage.toml").write_bytes(os.urandom(2048))
    (w / "types.toml").write_text('name = 5\nurdf = ["a"]\nee_frame = 3\nhome = "abc"\n')
    (w / "garbage.urdf").write_bytes(os.urandom(2048))
    (w / "empty.urdf").write_bytes(b"")
    (w / "nocollision.urdf").write_text('<robot name="r"><link name="link"/></robot>')
    (w / "garbage.stl").write_bytes(b"solid x\n" + os.urandom(4096))
    (w / "empty.stl").write_bytes(b"")
    tri = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], dtype="<f4")
    (w / "tiny.stl").write_bytes(
        b"\0" * 80 + struct.pack("<I", 1) + np.zeros(3, "<f4").tobytes() + tri.tobytes() + b"\0\0"
    )
    good = np.random.default_rng(0).uniform([0.4, -0.2, 0.3], [0.6, 0.2, 0.5], size=(500, 3))
    np.savez_compressed(w / "good.npz", points=good)
    # a 3.5 MB file whose 150M points (3.35 GiB as float64) are all zero
    _write_npz_bomb(w / "bomb.npz", 150_000_000)
    _npz_with_header(w / "npz_claims_huge.npz", (10**12, 3), b"\0" * 240)
    _npz_with_header(w / "npz_claims_neg.npz", (-5, 3), b"\0" * 240)
    (w / "npz_garbage.npz").write_bytes(os.urandom(4096))
    (w / "npz_empty.npz").write_bytes(b"")
    np.savez(w / "npz_nan.npz", points=np.full((10, 3), np.nan))
    np.savez(w / "npz_inf.npz", points=np.full((10, 3), np.inf))
    with zipfile.ZipFile(w / "npz_object.npz", "w") as z:  # a pickled object array
        import io

        buf = io.BytesIO()
        np.save(buf, np.array([object()] * 3, dtype=object), allow_pickle=True)
        z.writestr("points.npy", buf.getvalue())
    np.savez(w / "npz_complex.npz", points=np.ones((10, 3), dtype=complex) * (0.5 + 1j))
    np.savez(w / "npz_bool.npz", points=np.ones((10, 3), dtype=bool))
    np.savez(w / "npz_4col.npz", points=np.ones((10, 4)))
    np.savez(w / "npz_1d.npz", points=np.ones(30))
    np.savez(w / "npz_0d.npz", points=np.array(1.0))
    np.savez(w / "npz_zero_points.npz", points=np.zeros((0, 3)))
    np.savez(w / "npz_no_points.npz", other=np.zeros((10, 3)))
    np.savez(w / "npz_far_apart.npz", points=np.array([[-150.0, -150.0, -150.0], [150.0, 150.0, 150.0], [0.5, 0, 0.5]]))
    np.savez(w / "npz_far_origin.npz", points=np.array([[1e30, 0, 0]]))
    with open(w / "single.npy.npz", "wb") as f:  # a .npy array under a .npz name
        np.save(f, good)
    _ply_ascii(w / "ply_claims_huge_ascii.ply", 10**12, ["0 0 0", "1 1 1", "0.5 0.5 0.5"])
    _ply_binary(w / "ply_claims_huge_binary.ply", 10**12, good[:3])
    _ply_ascii(w / "ply_claims_neg.ply", -5, ["0 0 0"])
    (w / "ply_garbage.ply").write_bytes(b"ply\n" + os.urandom(4096))
    (w / "ply_empty.ply").write_bytes(b"")
    (w / "ply_header_only.ply").write_text("ply\nformat ascii 1.0\nend_header\n")
    _ply_ascii(w / "ply_nan.ply", 2, ["nan nan nan", "0 0 0"])
    (w / "ply_faces_only.ply").write_text(
        "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n3 0 1 2\n"
    )
    (w / "cloud.xyz").write_text("0 0 0\n1 1 1\n")

    # scenarios
    from planbench.reactive.sets import load_scenarios

    S = load_scenarios("dynamic-smoke")[0].to_dict()

    def scen(name: str, **changes: Any) -> None:
        jdump(name, {**S, **changes})

    scen("sc_good.json")
    scen("sc_nan_rate.json", control_rate=float("nan"))
    scen("sc_tiny_rate.json", control_rate=1e-300)
    scen("sc_huge_rate.json", control_rate=1e12)
    scen("sc_huge_horizon.json", horizon=1e300)
    scen("sc_neg_horizon.json", horizon=-1)
    scen("sc_str_rate.json", control_rate="fast")
    scen("sc_problem_int.json", problem=5)
    scen("sc_problem_missing.json", problem="missing_problem.json")
    scen("sc_problem_fifo.json", problem="fifo.json")
    scen("sc_problem_devzero.json", problem="devzero.json")
    scen("sc_problem_bad.json", problem="nan_start.json")
    scen("sc_fmt.json", format="planbench-scenario/7")
    scen("sc_moving_dict.json", moving_obstacles={"a": 1})
    mo = dict(S["moving_obstacles"][0]) if S["moving_obstacles"] else {"name": "m", "type": "sphere", "radius": 0.05}
    scen(
        "sc_moving_nan_vel.json",
        moving_obstacles=[{**mo, "motion": {"type": "velocity", "velocity": [float("nan"), 0, 0]}}],
    )
    scen("sc_moving_bad_motion.json", moving_obstacles=[{**mo, "motion": {"type": "teleport"}}])
    scen("sc_moving_motion_list.json", moving_obstacles=[{**mo, "motion": [1, 2]}])
    scen("sc_moving_appear_nan.json", moving_obstacles=[{**mo, "appear": float("nan")}])
    scen("sc_moving_appear_str.json", moving_obstacles=[{**mo, "appear": "soon"}])
    scen(
        "sc_moving_pointcloud.json", moving_obstacles=[{**mo, "type": "pointcloud", "path": "good.npz", "radius": 0.01}]
    )
    scen(
        "sc_moving_huge_speed.json",
        moving_obstacles=[{**mo, "motion": {"type": "velocity", "velocity": [1e308, 0, 0]}}],
    )
    scen("sc_sensing_res_tiny.json", sensing={"model": "truth", "resolution": 1e-9})
    scen("sc_sensing_rate_huge.json", sensing={"model": "truth", "rate": 1e12})
    scen("sc_sensing_model.json", sensing={"model": "lidar"})
    scen("sc_sensing_list.json", sensing=[1])
    scen("sc_camera_huge.json", sensing={"model": "depth", "cameras": [{"width": 10**6, "height": 10**6}]})
    scen("sc_camera_str.json", sensing={"model": "depth", "cameras": [{"width": "wide"}]})
    scen("sc_camera_float.json", sensing={"model": "depth", "cameras": [{"width": 1.5}]})
    scen("sc_camera_fov_nan.json", sensing={"model": "depth", "cameras": [{"fov": float("nan")}]})
    scen("sc_camera_pos_str.json", sensing={"model": "depth", "cameras": [{"position": "here"}]})
    scen("sc_camera_pos_short.json", sensing={"model": "depth", "cameras": [{"position": [1, 2]}]})
    scen("sc_camera_bad_key.json", sensing={"model": "depth", "cameras": [{"zoom": 2}]})
    scen("sc_metadata_list.json", metadata=[1])
    scen("sc_unknown_key.json", nope=1)
    (w / "sc_garbage.json").write_bytes(os.urandom(1000))
    (w / "sc_array.json").write_text("[]")
    (w / "sc_dir").mkdir()

    # suites
    def suite(name: str, text: str) -> None:
        (w / name).write_text(text)

    head = '[suite]\nname = "f"\nproblems = ["mbm:box/0001"]\n'
    planner = '[[planners]]\nplanner = "straight-line"\n'
    suite("s_empty.toml", "")
    (w / "s_binary.toml").write_bytes(os.urandom(512))
    suite("s_name_int.toml", '[suite]\nname = 5\nproblems = ["mbm:box/0001"]\n' + planner)
    suite("s_name_empty.toml", '[suite]\nname = ""\nproblems = ["mbm:box/0001"]\n' + planner)
    suite("s_problems_int.toml", '[suite]\nname = "f"\nproblems = 5\n' + planner)
    suite("s_problems_empty.toml", '[suite]\nname = "f"\nproblems = []\n' + planner)
    suite("s_problems_bad.toml", '[suite]\nname = "f"\nproblems = ["nan_start.json"]\n' + planner)
    suite("s_problems_fifo.toml", '[suite]\nname = "f"\nproblems = ["fifo.json"]\n' + planner)
    suite("s_seeds_neg.toml", head + "seeds = -1\n" + planner)
    suite("s_seeds_huge.toml", head + "seeds = 1000000000\n" + planner)
    suite("s_seeds_bool.toml", head + "seeds = [true]\n" + planner)
    suite("s_seeds_str.toml", head + 'seeds = "abc"\n' + planner)
    suite("s_seeds_float.toml", head + "seeds = [1.5]\n" + planner)
    suite("s_seeds_table.toml", head + "seeds = {a = 1}\n" + planner)
    suite("s_time_nan.toml", head + "time_limit = nan\n" + planner)
    suite("s_time_inf.toml", head + "time_limit = inf\n" + planner)
    suite("s_time_neg.toml", head + "time_limit = -1\n" + planner)
    suite("s_time_str.toml", head + 'time_limit = "5"\n' + planner)
    suite("s_time_huge.toml", head + "time_limit = 1e300\n" + planner)
    suite("s_time_tiny.toml", head + "time_limit = 1e-300\n" + planner)
    suite("s_grace_huge.toml", head + "grace = 1e300\n" + planner)
    suite("s_setup_huge.toml", head + "setup_timeout = 1e300\n" + planner)
    suite("s_validation_timeout_huge.toml", head + "validation_timeout = 1e300\n" + planner)
    suite("s_memory_nan.toml", head + "memory_limit = nan\n" + planner)
    suite("s_memory_neg.toml", head + "memory_limit = -1\n" + planner)
    suite("s_memory_bool.toml", head + "memory_limit = true\n" + planner)
    suite("s_memory_huge.toml", head + "memory_limit = 1e300\n" + planner)
    suite("s_memory_tiny.toml", head + "memory_limit = 1e-9\n" + planner)
    suite("s_memory_date.toml", head + "memory_limit = 1979-05-27\n" + planner)
    suite("s_validation_nan.toml", head + planner + "[validation]\nrequired_clearance = nan\n")
    suite("s_validation_neg.toml", head + planner + "[validation]\nrequired_clearance = -1.0\n")
    suite("s_validation_unknown.toml", head + planner + "[validation]\nnope = 1\n")
    suite("s_validation_str.toml", head + planner + '[validation]\nrequired_clearance = "x"\n')
    suite("s_planners_int.toml", head + "planners = 5\n")
    suite("s_planners_none.toml", head)
    suite("s_planner_unknown.toml", head + '[[planners]]\nplanner = "nope-planner"\n')
    suite("s_planner_module.toml", head + '[[planners]]\nplanner = "no_such_module:Thing"\n')
    suite("s_planner_int.toml", head + "[[planners]]\nplanner = 5\n")
    suite("s_planner_settings_int.toml", head + '[[planners]]\nplanner = "straight-line"\nsettings = 5\n')
    suite("s_planner_settings_bad.toml", head + '[[planners]]\nplanner = "straight-line"\nsettings = { nope = 1 }\n')
    suite(
        "s_planner_settings_type.toml",
        head + '[[planners]]\nplanner = "straight-line"\nsettings = { timed = "maybe" }\n',
    )
    suite("s_planner_settings_nan.toml", head + '[[planners]]\nplanner = "matrix-field"\nsettings = { gain = nan }\n')
    suite("s_planner_label_dup.toml", head + planner + planner)
    suite("s_planner_optional_str.toml", head + '[[planners]]\nplanner = "straight-line"\noptional = "no"\n')
    suite("s_unknown_table.toml", head + planner + "[extra]\na = 1\n")
    suite("s_unknown_key.toml", head + "colour = 1\n" + planner)
    suite("s_format.toml", head + 'format = "planbench-suite/9"\n' + planner)
    suite("s_both.toml", head + 'scenarios = ["dynamic-smoke"]\n' + planner)
    suite(
        "s_timing.toml",
        '[suite]\nname = "d"\nscenarios = ["dynamic-smoke"]\ntiming = "x"\n'
        '[[controllers]]\ncontroller = "matrix-field"\n',
    )
    dyn = '[suite]\nname = "d"\nscenarios = ["{sc}"]\n[[controllers]]\ncontroller = "matrix-field"\n'
    for sc in (
        "sc_garbage.json",
        "sc_array.json",
        "sc_dir",
        "sc_nan_rate.json",
        "sc_tiny_rate.json",
        "sc_huge_rate.json",
        "sc_huge_horizon.json",
        "sc_neg_horizon.json",
        "sc_str_rate.json",
        "sc_problem_int.json",
        "sc_problem_missing.json",
        "sc_problem_fifo.json",
        "sc_problem_devzero.json",
        "sc_problem_bad.json",
        "sc_fmt.json",
        "sc_moving_dict.json",
        "sc_moving_nan_vel.json",
        "sc_moving_bad_motion.json",
        "sc_moving_motion_list.json",
        "sc_moving_appear_nan.json",
        "sc_moving_appear_str.json",
        "sc_moving_pointcloud.json",
        "sc_moving_huge_speed.json",
        "sc_sensing_res_tiny.json",
        "sc_sensing_rate_huge.json",
        "sc_sensing_model.json",
        "sc_sensing_list.json",
        "sc_camera_huge.json",
        "sc_camera_str.json",
        "sc_camera_float.json",
        "sc_camera_fov_nan.json",
        "sc_camera_pos_str.json",
        "sc_camera_pos_short.json",
        "sc_camera_bad_key.json",
        "sc_metadata_list.json",
        "sc_unknown_key.json",
        "fifo.json",
        "devzero.json",
    ):
        suite(f"d_{sc.replace('.', '_')}.toml", dyn.replace("{sc}", sc))
    suite(
        "d_controller_unknown.toml",
        '[suite]\nname = "d"\nscenarios = ["dynamic-smoke"]\n[[controllers]]\ncontroller = "nope"\n',
    )
    suite(
        "d_scenario_unknown.toml",
        '[suite]\nname = "d"\nscenarios = ["dynamic:nope"]\n[[controllers]]\ncontroller = "matrix-field"\n',
    )
    suite(
        "d_scenario_range.toml",
        '[suite]\nname = "d"\nscenarios = ["dynamic:*/abc"]\n[[controllers]]\ncontroller = "matrix-field"\n',
    )

    # results databases
    good_db = w / "good.db"
    _results_db(good_db)
    (w / "notsqlite.db").write_text("hello " * 1000)
    (w / "empty.db").write_bytes(b"")
    conn = sqlite3.connect(w / "other.db")
    conn.execute("CREATE TABLE t (x)")
    conn.commit()
    conn.close()
    data = good_db.read_bytes()
    (w / "truncated.db").write_bytes(data[: len(data) // 2])
    (w / "header_only.db").write_bytes(data[:100])
    damaged = bytearray(data)
    damaged[len(data) // 2 : len(data) // 2 + 4096] = os.urandom(4096)
    (w / "damaged.db").write_bytes(bytes(damaged))
    _db_variant(good_db, w / "meta_only.db", "DROP TABLE runs;")
    _db_variant(good_db, w / "wrong_schema.db", "UPDATE meta SET value = 'planbench-results/99';")
    _db_variant(good_db, w / "runs_missing_cols.db", "ALTER TABLE runs DROP COLUMN status;")
    _db_variant(good_db, w / "bad_json.db", "UPDATE runs SET info = 'not json', checks = '{{', planner_settings = '[';")
    _db_variant(good_db, w / "bad_blob.db", "UPDATE runs SET path = x'deadbeef', times = x'00';")
    _db_variant(good_db, w / "bad_types.db", "UPDATE runs SET seed = 'abc', planning_time = 'slow', success = 'yes';")
    _db_variant(good_db, w / "null_keys.db", "UPDATE runs SET status = NULL, success = NULL, family = NULL;")
    _db_variant(good_db, w / "bad_problem.db", "UPDATE runs SET problem = 'nope:nothing/' || id;")
    _db_variant(good_db, w / "nan_values.db", "UPDATE runs SET planning_time = 1e999, min_clearance = -1e999;")
    _db_variant(good_db, w / "bad_suite_json.db", "UPDATE suites SET definition = 'garbage', settings = '[1';")
    import io

    big = io.BytesIO()
    claim = {"descr": "<f8", "fortran_order": False, "shape": (10**12, 7)}
    np.lib.format.write_array_header_1_0(big, claim)  # type: ignore[attr-defined]
    conn = sqlite3.connect(w / "good.db")
    conn.close()
    shutil.copy(good_db, w / "huge_blob.db")
    conn = sqlite3.connect(w / "huge_blob.db")
    conn.execute("UPDATE runs SET path = ?", (big.getvalue() + b"\0" * 64,))
    conn.commit()
    conn.close()
    shutil.copy(good_db, w / "path_3d.db")
    conn = sqlite3.connect(w / "path_3d.db")
    b3 = io.BytesIO()
    np.save(b3, np.zeros((4, 3, 2)))
    conn.execute("UPDATE runs SET path = ?", (b3.getvalue(),))
    conn.commit()
    conn.close()
    (w / "results_dir.db").mkdir()
    (w / "out_dir").mkdir()
    (w / "afile").write_text("x")


# --- the cases ------------------------------------------------------------------------------------


def cases() -> list[Case]:
    out: list[Case] = []

    def add(name: str, *args: str, module: str = "planbench.cli.main", expect: str = "refused") -> None:
        out.append(Case(name, list(args), module, expect))

    plan_files = [
        "empty.json", "garbage.json", "truncated.json", "array.json", "null.json", "string.json", "deep.json",
        "deep_obj.json", "utf16.json", "latin1.json", "bigint.json", "huge.json",
        "nan_start.json", "inf_goal.json", "huge_start.json", "overflow_start.json", "short_start.json",
        "long_start.json", "empty_start.json", "goal_out_of_reach.json", "goal_nan_pose.json", "goal_zero_quat.json",
        "goal_q_limits.json", "start_limits.json", "goal_frame.json", "neg_tol.json", "zero_tol.json", "nan_tol.json",
        "huge_tol.json", "empty_id.json", "long_id.json", "ctrl_id.json", "fmt.json", "no_goal.json",
        "goal_list.json", "robot_missing_toml.json", "robot_garbage_toml.json", "robot_dir.json", "robot_fifo.json",
        "robot_devzero.json", "robot_dict_bad_urdf.json", "robot_dict_dir_urdf.json", "robot_dict_fifo_urdf.json",
        "robot_dict_devzero_urdf.json", "robot_dict_empty_urdf.json", "robot_dict_nocoll_urdf.json",
        "robot_dict_types.json", "robot_toml_types.json", "override_unknown_joint.json", "override_nan.json",
        "override_limits_inverted.json", "override_vel_neg.json", "override_vel_zero.json", "scene_missing.json",
        "scene_dir.json", "scene_fifo.json", "scene_devzero.json", "scene_garbage.json", "scene_self.json",
        "scene_obstacles_dict.json", "box_nan.json", "box_inf_size.json", "box_neg.json", "box_str_size.json",
        "box_int_size.json", "box_bad_quat.json", "box_nested.json", "sphere_zero.json", "sphere_str.json",
        "sphere_list.json", "cyl_nan.json", "unknown_type.json", "dup_name.json", "mesh_missing.json",
        "mesh_garbage.json", "mesh_empty.json", "mesh_dir.json", "mesh_fifo.json", "mesh_devzero.json",
        "mesh_scale_nan.json", "mesh_scale_zero.json", "fifo.json", "devzero.json", "loop.json", "adir.json",
        "missing.json", "sc_good.json",
    ]  # fmt: skip
    for f in plan_files:
        add(f"plan --problem {f}", "plan", "--problem", f, "--time-limit", "2")
    for c in out:  # refused as runs (exit code 1, the reason named in the table), not as files
        if c.args[2] in ACCEPTED_PROBLEMS:
            c.expect = "any"
    add("plan --problem box_huge.json", "plan", "--problem", "box_huge.json", "--time-limit", "2", expect="any")
    add("plan --problem box_far.json", "plan", "--problem", "box_far.json", "--time-limit", "2", expect="any")
    for name in (
        "pc_bomb_npz", "pc_npz_claims_huge_npz", "pc_npz_claims_neg_npz", "pc_npz_garbage_npz", "pc_npz_empty_npz",
        "pc_npz_nan_npz", "pc_npz_inf_npz", "pc_npz_object_npz", "pc_npz_complex_npz", "pc_npz_bool_npz",
        "pc_npz_4col_npz", "pc_npz_1d_npz", "pc_npz_0d_npz", "pc_npz_zero_points_npz", "pc_npz_no_points_npz",
        "pc_npz_far_origin_npz", "pc_single_npy_npz", "pc_ply_claims_huge_ascii_ply",
        "pc_ply_claims_huge_binary_ply", "pc_ply_claims_neg_ply", "pc_ply_garbage_ply", "pc_ply_empty_ply",
        "pc_ply_header_only_ply", "pc_ply_nan_ply", "pc_ply_faces_only_ply", "pc_fifo_npz", "pc_devzero_ply",
        "pc_adir_npz", "pc_cloud_xyz", "pc_tiny_radius", "pc_nan_radius",
    ):  # fmt: skip
        add(f"plan --problem {name}.json", "plan", "--problem", f"{name}.json", "--time-limit", "2")
    # accepted by design or not: these must at least not blow up
    for name in ("pc_huge_radius", "pc_npz_far_apart_npz", "pc_far_apart_small_radius", "pc_good"):
        add(f"plan --problem {name}.json", "plan", "--problem", f"{name}.json", "--time-limit", "2", expect="any")
        add(f"field --problem {name}.json", "field", "--problem", f"{name}.json", "--out", "f.png", expect="any")
        add(f"plan matrix-field --problem {name}.json", "plan", "--problem", f"{name}.json", "--planner",
            "matrix-field", "--time-limit", "3", expect="any")  # fmt: skip
    add("field --problem box_huge.json", "field", "--problem", "box_huge.json", "--out", "f.png", expect="any")
    add("field --problem box_far.json", "field", "--problem", "box_far.json", "--out", "f.png", expect="any")

    # plan: arguments
    mb = ["plan", "--problem", "mbm:box/0001"]
    for v in ("nan", "inf", "-1", "0", "abc", "1e308", "1e-320"):
        add(f"plan --time-limit {v}", *mb, "--time-limit", v, expect="any" if v in ("1e-320",) else "refused")
    for v in ("-1", "99999999999999999999", "abc", "1.5"):
        add(f"plan --seed {v}", *mb, "--seed", v)
    for sel in ("", "mbm:box/0000", "mbm:box/abc", "mbm:box/99999999999999999999999999", "mbm:box/5-2",
                "gen:", "gen:nope", "examples:nope", "mbm:", "/", "/dev/zero", "/dev/null", "fifo"):  # fmt: skip
        add(
            f"plan --problem {sel!r}",
            "plan",
            "--problem",
            sel,
            "--time-limit",
            "2",
            expect="any" if sel in ("mbm:", "gen:") else "refused",
        )  # fmt: skip  (every problem of a set)
    add("plan --planner nope", *mb, "--planner", "nope")
    add("plan --planner module:Attr", *mb, "--planner", "no_such_mod:Thing")
    add("plan --planner planbench:nope", *mb, "--planner", "planbench:nope")
    add("plan --planner ''", *mb, "--planner", "")
    add("plan --set =", *mb, "--set", "=")
    add("plan --set timed=maybe", *mb, "--set", "timed=maybe")
    add("plan --set gain=nan (matrix-field)", *mb, "--planner", "matrix-field", "--set", "gain=nan")
    add("plan --set resolution=1e-9 (matrix-field)", *mb, "--planner", "matrix-field", "--set", "resolution=1e-9")
    add("plan --set resolution=0 (matrix-field)", *mb, "--planner", "matrix-field", "--set", "resolution=0")
    add("plan --set params=[ (ompl)", *mb, "--planner", "ompl-rrtconnect", "--set", "params=[")
    add("plan --json out_dir", *mb, "--json", "out_dir")
    add("plan --json missing/x.json", *mb, "--json", "missing_dir/x.json")
    add("plan --json fifo", *mb, "--json", "fifo", "--time-limit", "2")
    add("plan --replay out_dir", "plan", "--problem", "mbm:table_pick/0001", "--replay", "out_dir")
    add("plan --plot out_dir", "plan", "--problem", "mbm:box/0001", "--planner", "matrix-field", "--plot", "out_dir")

    # bench
    bout = ["--out", "{OUT}", "--no-progress"]
    suites = sorted(p for p in SUITE_NAMES)
    for s in suites:
        add(f"bench --suite {s}", "bench", "--suite", s, *bout, "-j", "1")
    for s in ("s_time_huge.toml", "s_time_tiny.toml", "s_grace_huge.toml", "s_setup_huge.toml",
              "s_validation_timeout_huge.toml", "s_memory_huge.toml", "s_memory_tiny.toml",
              "s_planner_optional_str.toml", "d_sc_huge_horizon_json.toml", "d_sc_tiny_rate_json.toml",
              "d_sc_huge_rate_json.toml", "d_sc_sensing_res_tiny_json.toml", "d_sc_sensing_rate_huge_json.toml",
              "d_sc_camera_huge_json.toml", "d_sc_moving_huge_speed_json.toml",
              # problems whose start or goal is unusable are failed runs, as in plan; a negative
              # required clearance is allowed (ValidationSettings: finite)
              "s_problems_bad.toml", "d_sc_problem_bad_json.toml", "s_validation_neg.toml"):  # fmt: skip
        for c in out:
            if c.name == f"bench --suite {s}":
                c.expect = "any"
    for s in ("adir", "fifo", "devzero.toml", "missing.toml", "", "loop.json"):
        add(f"bench --suite {s!r}", "bench", "--suite", s, *bout)
    sm = ["bench", "--problems", "mbm:box/0001", "--planners", "straight-line", "-j", "1", "--no-progress"]
    for v in (
        "",
        "-",
        "a-b",
        "1-",
        "0,0",
        "-5",
        "1e3",
        " ",
        "0-1000000",
        ",",
        "0,,1",
        "9223372036854775807-9223372036854775807",
    ):
        add(f"bench --seeds {v!r}", *sm, "--seeds", v, "--out", "{OUT}",
            expect="any" if v.startswith("922") or v == "0,,1" else "refused")  # fmt: skip
    for v in ("nan", "inf", "-inf", "1e308", "-0", "abc"):
        add(
            f"bench --time-limit {v}",
            *sm,
            "--time-limit",
            v,
            "--out",
            "{OUT}",
            expect="any" if v == "1e308" else "refused",
        )
    for v in ("nan", "inf", "-0", "1e-9", "1e308", "", "0x10"):
        add(f"bench --memory-limit {v!r}", *sm, "--memory-limit", v, "--out", "{OUT}",
            expect="any" if v in ("1e-9", "1e308", "-0") else "refused")  # fmt: skip
    for v in ("-1", "abc", "1e9"):
        add(f"bench --jobs {v}", *sm, "--jobs", v, "--out", "{OUT}", expect="any" if v == "1e9" else "refused")
    add("bench --jobs 100000", *sm[:-3], "--jobs", "100000", "--no-progress", "--out", "{OUT}", expect="any")
    for db in ("notsqlite.db", "other.db", "truncated.db", "header_only.db", "damaged.db", "meta_only.db",
               "wrong_schema.db", "runs_missing_cols.db", "results_dir.db", "fifo.db", "devzero.db", "devnull.db",
               "missing_dir/r.db", "", "afile/r.db"):  # fmt: skip
        ok = "any" if db in ("meta_only.db", "runs_missing_cols.db") else "refused"  # planbench's: it is used
        copied = db.endswith(".db") and "/" not in db and not db.startswith(("fifo", "dev"))
        target = "{COPY:" + db + "}" if copied else db  # the command may write it: a copy per case
        if db == "missing_dir/r.db":  # bench makes the folder (by design): one of the case's own
            target, ok = "{OUT}_dir/r.db", "any"
        add(f"bench --out {db!r}", *sm, "--out", target, expect=ok)
        add(f"bench --resume --out {db!r}", *sm, "--resume", "--out", target, expect=ok)
    add("bench --out empty.db", *sm, "--out", "{COPY:empty.db}", expect="any")
    for f in ("nan_start.json", "fifo.json", "devzero.json", "adir", "garbage.json", "pc_bomb_npz.json",
              "pc_ply_claims_huge_binary_ply.json", "scene_fifo.json"):  # fmt: skip
        add(f"bench --problems {f}", *sm, "--problems", f, "--out", "{OUT}",
            expect="any" if f == "nan_start.json" else "refused")  # fmt: skip
    add("bench --planners ,,", "bench", "--planners", ",,", "--out", "{OUT}")
    add("bench --planners nope", *sm[:3], "--planners", "nope", "--out", "{OUT}", "--no-progress")
    add("bench --set =x", *sm, "--set", "=x", "--out", "{OUT}")
    add("bench --set nope=1", *sm, "--set", "nope=1", "--out", "{OUT}")
    add("bench --ray-runtime-env []", *sm, "--executor", "ray", "--ray-runtime-env", "[]", "--out", "{OUT}")
    add("bench --ray-runtime-env {", *sm, "--executor", "ray", "--ray-runtime-env", "{", "--out", "{OUT}")
    for addr in ("127.0.0.1:1", "10.255.255.1:6379", "192.0.2.1:6379", "nonexistent.invalid:6379", "ray://127.0.0.1:1",
                 "garbage", "host:notaport", "127.0.0.1:99999", ":::", "[::1]:1"):  # fmt: skip
        add(f"bench --executor ray --address {addr}", *sm, "--executor", "ray", "--address", addr, "--out", "{OUT}")
    add("bench --address without ray", *sm, "--address", "auto", "--out", "{OUT}")

    # report / export / replay
    dbs = ["notsqlite.db", "empty.db", "other.db", "truncated.db", "header_only.db", "damaged.db", "meta_only.db",
           "wrong_schema.db", "runs_missing_cols.db", "bad_json.db", "bad_blob.db", "bad_types.db", "null_keys.db",
           "bad_problem.db", "nan_values.db", "bad_suite_json.db", "huge_blob.db", "path_3d.db", "results_dir.db",
           "fifo.db", "devzero.db", "devnull.db", "missing.db", "good.db"]  # fmt: skip
    # planbench files with odd values where the command does not read them: reading them is fine
    # planbench files with odd values where a command does not read them are fine for it; a column
    # an older file lacks reads as missing values (runs_missing_cols), by design
    readable = {"good.db", "empty.db", "bad_json.db", "null_keys.db", "bad_problem.db", "nan_values.db"}
    readable.add("runs_missing_cols.db")
    no_arrays = readable | {"bad_blob.db", "huge_blob.db", "path_3d.db", "bad_suite_json.db"}  # paths not read
    for db in dbs:
        add(f"report {db}", "report", db, expect="any" if db in no_arrays else "refused")
        ok = "any" if db in readable | {"path_3d.db"} else "refused"
        add(f"report {db} --html", "report", db, "--html", "rep.html", "--replays", expect=ok)
        ok = "any" if db in readable | {"path_3d.db", "bad_suite_json.db"} else "refused"
        add(f"export {db} csv --paths", "export", db, "--format", "csv", "--paths", "--out", "e.csv", expect=ok)
        ok = "any" if db in no_arrays else "refused"
        add(f"export {db} ompl-log", "export", db, "--format", "ompl-log", "--out", "logs", expect=ok)
        ok = "any" if db in readable - {"empty.db", "bad_problem.db"} | {"bad_suite_json.db"} else "refused"
        add(f"replay {db} --run 1", "replay", db, "--run", "1", "--out", "rp.html", expect=ok)
    add("export good.db parquet", "export", "good.db", "--format", "parquet", "--out", "e.parquet", expect="any")
    add(
        "export good.db planner-arena", "export", "good.db", "--format", "planner-arena", "--out", "pa.db", expect="any"
    )
    add("report good.db --plots afile", "report", "good.db", "--plots", "afile")
    add("report good.db --csv fifo", "report", "good.db", "--csv", "fifo")
    add("report good.db --markdown /dev/full", "report", "good.db", "--markdown", "/dev/full")
    add("report good.db --problems bad", "report", "good.db", "--problems", "mbm:nope")
    add("report good.db --problems fifo.json", "report", "good.db", "--problems", "fifo.json")
    add("export good.db --out out_dir csv", "export", "good.db", "--format", "csv", "--out", "out_dir")
    add("export good.db --out afile ompl-log", "export", "good.db", "--format", "ompl-log", "--out", "afile")
    add("export good.db --out fifo csv", "export", "good.db", "--format", "csv", "--out", "fifo")
    for run in ("-1", "0", "99999999", str(2**70), "abc"):
        add(f"replay good.db --run {run}", "replay", "good.db", "--run", run, "--out", "rp.html")
    add("replay good.db --out out_dir", "replay", "good.db", "--run", "1", "--out", "out_dir")

    # field / kernel / bench-field
    for a in (["--resolution", "0"], ["--resolution", "-1"], ["--resolution", "nan"], ["--resolution", "inf"],
              ["--resolution", "1e-5"], ["--resolution", "1e6"], ["--slice", "garbage"], ["--slice", "q=0.3"],
              ["--slice", "z=nan"], ["--slice", "z=inf"], ["--slice", "z=abc"], ["--slice", "z"],
              ["--slice", "z=100"], ["--outside", "2"], ["--outside", "nan"], ["--reach", "0"], ["--reach", "-1"],
              ["--reach", "nan"], ["--reach", "1e6"], ["--width", "-1"], ["--width", "1e6"], ["--gain", "nan"],
              ["--gain", "inf"], ["--sigma", "0"], ["--sigma", "-1"], ["--power", "nan"], ["--power", "-1"],
              ["--out", "out_dir"], ["--out", "missing_dir/f.png"], ["--out", "fifo"], ["--problem", "fifo.json"],
              ["--problem", "nan_start.json"], ["--problem", "pc_bomb_npz.json"]):  # fmt: skip
        unused = a[0] in ("--sigma", "--power") or a == ["--slice", "z=100"] or a == ["--problem", "nan_start.json"]
        add(f"field {' '.join(a)}", "field", *(a if "--out" in a else [*a, "--out", "f.png"]),
            expect="any" if unused or a == ["--out", "missing_dir/f.png"] else "refused")  # fmt: skip
    for a in (["--resolution", "0"], ["--resolution", "nan"], ["--resolution", "1e-9"], ["--reach", "1e6"],
              ["--reach", "nan"], ["--width", "1e6"], ["--sigma", "-1"], ["--out", "out_dir"],
              ["--profile", "all", "--resolution", "1e-9"], ["--profile", "all", "--reach", "nan"]):  # fmt: skip
        add(
            f"kernel {' '.join(a)}",
            "kernel",
            *(a if "--out" in a else [*a, "--out", "k.png"]),
            expect="any" if a[0] == "--sigma" else "refused",
        )  # fmt: skip  (no gaussian profile: unused)
    for a in (["--sizes", "-1"], ["--sizes", "0"], ["--sizes", "100000"], ["--lengths", "2"], ["--lengths", "-1"],
              ["--lengths", "100001"], ["--repeat", "-1"], ["--repeat", "0"], ["--budget", "nan"], ["--points", "-1"],
              ["--dtypes", "int8"]):  # fmt: skip
        add(
            f"bench-field --quick {' '.join(a)}",
            "bench-field",
            "--quick",
            *a,
            expect="any" if a[0] in ("--sizes", "--lengths") else "refused",
        )  # fmt: skip  (--quick sets them)
        if a[0] in ("--sizes", "--lengths"):
            add(f"bench-field {' '.join(a)}", "bench-field", *a)

    # check
    for a in (["nope"], ["no_such_mod:Thing"], ["straight-line", "--timeout", "nan"],
              ["straight-line", "--timeout", "-1"], ["straight-line", "--timeout", "1e308"], ["nope", "--controller"],
              [""]):  # fmt: skip
        add(f"check {' '.join(a)}", "check", *a, expect="any" if "1e308" in a else "refused")

    # python -m planbench.problems.generate (the maintainers' regeneration tool)
    g = "planbench.problems.generate"
    add("generate --families nope", "--out", "gen_out", "--families", "nope", module=g)
    add("generate --robots nope", "--out", "gen_out", "--robots", "nope", "-n", "1", module=g)
    add("generate -n -1", "--out", "gen_out", "-n", "-1", module=g)
    add("generate --seed -1", "--out", "gen_out", "--seed", "-1", "-n", "1", "--families", "shelf", "--robots",
        "panda", module=g)  # fmt: skip
    add("generate --out afile", "--out", "afile", "-n", "1", "--families", "shelf", "--robots", "panda", module=g)
    add("generate --solvability nan", "--out", "gen_out", "--solvability", "nan", module=g)
    add("generate --solvability 1 (no manifest)", "--out", "out_dir", "--solvability", "1", module=g)
    return out


SUITE_NAMES: list[str] = []
ACCEPTED_PROBLEMS = {
    # well-formed files whose start or goal is unusable: `plan` reports them as failed runs
    # (invalid_start, invalid_goal) with the reason, exit code 1, as a benchmark records them
    "nan_start.json", "inf_goal.json", "huge_start.json", "goal_out_of_reach.json", "goal_nan_pose.json",
    "goal_q_limits.json", "start_limits.json", "goal_frame.json",
    # planned like any problem: a valid selector, or failed runs that name the reason
    "mbm:", "gen:",
    # unusual but valid
    "latin1.json", "huge_tol.json", "empty_id.json", "long_id.json", "ctrl_id.json",
}  # fmt: skip


# --- running --------------------------------------------------------------------------------------


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (AS_LIMIT, AS_LIMIT))


def run_case(case: Case, w: Path, timeout: float, memory_flag_mib: float) -> dict[str, Any]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    env.setdefault("PLANBENCH_BACKGROUND_COMPILE", "0")
    env["COLUMNS"] = "120"
    tag = f"{abs(hash(case.name)):x}"
    out_f, err_f = w / f".out.{tag}", w / f".err.{tag}"
    outdb = f"r_{tag}.db"  # each case its own results file: cases run side by side
    args = [a.replace("{OUT}", outdb) for a in case.args]
    for i, a in enumerate(args):  # a copy of an input the command would change (bench --out)
        if a.startswith("{COPY:"):
            args[i] = f"{outdb}.{a[6:-1]}"
            if (w / a[6:-1]).is_dir():
                (w / args[i]).mkdir()
            else:
                shutil.copy(w / a[6:-1], w / args[i])
    cmd = [sys.executable, "-m", case.module, *args]
    started = time.monotonic()
    with open(out_f, "wb") as o, open(err_f, "wb") as e:
        proc = subprocess.Popen(
            cmd, cwd=w, env=env, stdout=o, stderr=e, stdin=subprocess.DEVNULL, preexec_fn=_limit, start_new_session=True
        )
        hung = False
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() - started > timeout:
                hung = True
                try:
                    os.killpg(proc.pid, 9)
                except ProcessLookupError:
                    pass
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.05)
        proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.monotonic() - started
    stdout = out_f.read_text(errors="replace")
    stderr = err_f.read_text(errors="replace")
    out_f.unlink()
    err_f.unlink()
    for f in w.glob(outdb + "*"):
        shutil.rmtree(f) if f.is_dir() else f.unlink()
    rss_mib = usage.ru_maxrss / 1024
    rc = proc.returncode
    lines = [x for x in stderr.splitlines() if x.strip()]
    if hung:
        verdict = "HANG"
    elif "Traceback" in stderr or "Traceback" in stdout:
        verdict = "TRACEBACK"
    elif rc == 2 and any(" error: " in x or x.startswith("planbench: error:") for x in lines):
        verdict = "good"
    elif rc in (0, 1):
        verdict = "ran" if case.expect == "any" else "ACCEPTED"
    else:
        verdict = "EXIT"
    if rss_mib > memory_flag_mib:
        verdict += "+MEMORY"
    errors = [x for x in lines if "error:" in x]
    return {
        "name": case.name,
        "command": " ".join([case.module, *case.args]),
        "verdict": verdict,
        "rc": rc,
        "wall": round(wall, 2),
        "rss_mib": round(rss_mib),
        "error": (errors[-1] if errors else (lines[-1] if lines else ""))[:400],
        "stderr_tail": "\n".join(lines[-12:])[-3000:],
        "stdout_tail": stdout[-600:],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--only", action="append", help="run only cases whose name holds this text (repeatable)")
    ap.add_argument("--memory-flag", type=float, default=1024.0, help="[MiB] peak resident memory that is flagged")
    ap.add_argument("--json", type=Path, help="write every result here")
    ap.add_argument("--keep", type=Path, help="make the inputs in this folder (kept) instead of a temporary one")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    args = ap.parse_args(argv)

    w = args.keep or Path(tempfile.mkdtemp(prefix="planbench-fuzz-"))
    try:
        if not (w / ".complete").exists():
            shutil.rmtree(w, ignore_errors=True)
            w.mkdir(parents=True, exist_ok=True)
            t = time.monotonic()
            make_inputs(w)
            (w / ".complete").write_text("")
            print(f"inputs written to {w} in {time.monotonic() - t:.0f} s", flush=True)
        SUITE_NAMES[:] = sorted(p.name for p in w.glob("[sd]_*.toml"))
        todo = cases()
        if args.only:
            todo = [c for c in todo if any(o in c.name for o in args.only)]
        if args.list:
            for c in todo:
                print(c.name)
            print(f"{len(todo)} cases")
            return 0
        print(f"{len(todo)} cases, {args.jobs} at a time, timeout {args.timeout:g} s", flush=True)
        results = []
        with ThreadPoolExecutor(args.jobs) as pool:
            for r in pool.map(lambda c: run_case(c, w, args.timeout, args.memory_flag), todo):
                results.append(r)
                mark = "  " if r["verdict"] in ("good", "ran") else "!!"
                print(
                    f"{mark} {r['verdict']:<10} rc={r['rc']:<4} {r['wall']:6.1f}s {r['rss_mib']:6d}MiB  {r['name']}",
                    flush=True,
                )
                if mark == "!!" or r["verdict"] == "ran":
                    print("      " + r["error"].replace("\n", " ")[:300], flush=True)
        bad = [r for r in results if r["verdict"] not in ("good", "ran")]
        counts: dict[str, int] = {}
        for r in results:
            counts[r["verdict"]] = counts.get(r["verdict"], 0) + 1
        print(f"\n{len(results)} cases: " + ", ".join(f"{v} {k}" for k, v in sorted(counts.items())))
        for r in bad:
            print(f"\n== {r['verdict']}: {r['command']}\n{r['stderr_tail']}")
        if args.json:
            args.json.write_text(json.dumps(results, indent=1))
        return 1 if bad else 0
    finally:
        if not args.keep:
            shutil.rmtree(w, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())

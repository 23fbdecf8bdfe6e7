"""More bad input, found by ``benchmarks/fuzz_bad_inputs.py``: each case is a named error (exit code 2,
no traceback) within seconds, before anything large is allocated and before any run.

Files that are not regular files (a FIFO would block the open, ``/dev/zero`` would be read until
memory runs out), text that is not UTF-8 or JSON too deep to parse, point clouds that claim more
points than planbench reads or than the file holds, grids and kernels past their cell limits,
outputs that are folders or FIFOs nobody reads, damaged values in a results file, and Ray cluster
addresses that cannot be reached. The commands run in this process (``planbench.cli.main``) wherever
the refusal comes before any worker starts; the Ctrl-C tests run the CLI in a subprocess."""

from __future__ import annotations

import io
import json
import os
import selectors
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

import planbench
from planbench.bench.db import ResultsDB
from planbench.bench.records import failure_record
from planbench.cli.main import main
from planbench.errors import ProblemFileError, ResourceLimitError
from planbench.files.inputs import InputFileError, read_json
from planbench.geometry.occupancy import MAX_GRID_CELLS, OccupancyGrid, grid_shape
from planbench.geometry.pointcloud import MAX_POINTS, VoxelCloud

TESTS = Path(__file__).parent
PLANBENCH = [sys.executable, "-m", "planbench.cli.main"]


def _refused(args: list[str], capsys, *needles: str) -> str:
    """main(args) exits 2 with one named error holding every needle; returns stderr."""
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("planbench: error: ") and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


@pytest.fixture(scope="module")
def problem_dict() -> dict:
    d = planbench.load_problems("mbm:box/0001")[0].to_dict()
    d["id"] = "bad"
    return d


def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


def _devzero(path: Path) -> Path:
    path.symlink_to("/dev/zero")
    return path


def _with_obstacle(problem_dict: dict, folder: Path, obstacle: dict, name: str = "p.json") -> Path:
    scene = dict(problem_dict["scene"])
    scene["obstacles"] = [*scene["obstacles"], obstacle]
    path = folder / name
    path.write_text(json.dumps({**problem_dict, "scene": scene}))
    return path


# -- input files: not regular, not UTF-8, not parseable ------------------------------------------------

FILE_CASES = {
    "fifo": (lambda p: _fifo(p), "FIFO (named pipe), not a regular file"),
    "dev-zero": (lambda p: _devzero(p), "a device, not a regular file"),
    "binary": (lambda p: p.write_bytes(b"\xcf\xff" + bytes(range(256)) * 4), "not UTF-8 text"),
    "utf-16": (lambda p: p.write_bytes('{"a": 1}'.encode("utf-16")), "not UTF-8 text"),
    "deep": (lambda p: p.write_text("[" * 100_000 + "]" * 100_000), "nested too deeply"),
    "long-integer": (lambda p: p.write_text('{"start": [' + "9" * 5000 + "]}"), "4300 digits"),
}


@pytest.mark.parametrize("case", sorted(FILE_CASES))
def test_a_problem_file_that_cannot_be_read_is_named(case, tmp_path, capsys):
    make, needle = FILE_CASES[case]
    path = tmp_path / "p.json"
    make(path)
    _refused(["plan", "--problem", str(path)], capsys, str(path), needle)


@pytest.mark.parametrize("case", ["fifo", "dev-zero", "binary"])
def test_scene_robot_suite_and_scenario_files_are_read_the_same_way(case, problem_dict, tmp_path, capsys):
    make, needle = FILE_CASES[case]
    scene = tmp_path / "scene.json"
    make(scene)
    (tmp_path / "p1.json").write_text(json.dumps({**problem_dict, "scene": "scene.json"}))
    _refused(["plan", "--problem", str(tmp_path / "p1.json")], capsys, str(scene), needle)
    make(tmp_path / "robot.toml")
    (tmp_path / "p2.json").write_text(json.dumps({**problem_dict, "robot": "robot.toml"}))
    _refused(["plan", "--problem", str(tmp_path / "p2.json")], capsys, "robot.toml", needle)
    make(tmp_path / "suite.toml")
    out = tmp_path / "r.db"
    _refused(["bench", "--suite", str(tmp_path / "suite.toml"), "--out", str(out)], capsys, "suite.toml", needle)
    make(tmp_path / "sc.json")
    (tmp_path / "dyn.toml").write_text(
        f'[suite]\nname = "d"\nscenarios = ["{tmp_path / "sc.json"}"]\n[[controllers]]\ncontroller = "matrix-field"\n'
    )
    _refused(["bench", "--suite", str(tmp_path / "dyn.toml"), "--out", str(out)], capsys, "sc.json", needle)
    assert not out.exists()


def test_read_json_refuses_a_file_past_its_limit(tmp_path):
    path = tmp_path / "big.json"
    path.write_text('{"pad": "' + "x" * 2000 + '"}')
    with pytest.raises(InputFileError, match="files of this kind are read up to 1 kiB"):
        read_json(path, limit=1024)
    assert read_json(path, limit=4096)["pad"] == "x" * 2000


# -- problem contents that used to pass the loader ---------------------------------------------------------


@pytest.mark.parametrize(
    "obstacle, needle",
    [
        ({"path": "garbage.stl"}, "coal cannot load it"),
        ({"path": "empty.stl"}, "coal cannot load it"),
        ({"path": "fifo.stl"}, "FIFO (named pipe)"),
        ({"path": "tiny.stl", "scale": [float("nan")] * 3}, "NaN"),
        ({"path": "tiny.stl", "scale": [1, 0, 1]}, "scale must be non-zero"),
    ],
    ids=["garbage", "empty", "fifo", "scale-nan", "scale-zero"],
)
def test_a_bad_mesh_is_named_when_the_scene_loads(obstacle, needle, problem_dict, tmp_path, capsys):
    (tmp_path / "garbage.stl").write_bytes(b"solid x\n" + bytes(range(256)) * 8)
    (tmp_path / "empty.stl").write_bytes(b"")
    _fifo(tmp_path / "fifo.stl")
    triangle = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], "<f4").tobytes()
    (tmp_path / "tiny.stl").write_bytes(b"\0" * 80 + (1).to_bytes(4, "little") + bytes(12) + triangle + b"\0\0")
    path = _with_obstacle(problem_dict, tmp_path, {"name": "m", "type": "mesh", **obstacle})
    _refused(["plan", "--problem", str(path)], capsys, str(path), needle)
    good = _with_obstacle(problem_dict, tmp_path, {"name": "m", "type": "mesh", "path": "tiny.stl"}, "good.json")
    assert planbench.load_problems(good)[0].scene.obstacles[-1].type == "mesh"


def test_a_fixed_joint_held_at_nan_is_named(problem_dict, tmp_path, capsys):
    path = tmp_path / "p.json"
    path.write_text(json.dumps({**problem_dict, "robot_overrides": {"fixed_joints": {"panda_finger_joint1": "NaN"}}}))
    path.write_text(path.read_text().replace('"NaN"', "NaN"))
    _refused(["plan", "--problem", str(path)], capsys, "panda_finger_joint1", "finite")


# -- point clouds ---------------------------------------------------------------------------------------


def _npz_claiming(path: Path, shape: tuple, data: bytes, descr: str = "<f8") -> Path:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("points.npy", buf.getvalue() + data)
    return path


def _zeros_npz(path: Path, n_points: int) -> Path:
    """A deflated .npz of ``n_points`` zeros, written in chunks (about 1000:1)."""
    header = {"descr": "<f8", "fortran_order": False, "shape": (n_points, 3)}
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        with z.open("points.npy", "w", force_zip64=True) as f:
            np.lib.format.write_array_header_1_0(f, header)
            left = n_points * 24
            while left:
                f.write(bytes(min(left, 1 << 24)))
                left -= min(left, 1 << 24)
    return path


def _ply(path: Path, claimed: int, body: bytes, fmt: str = "ascii") -> Path:
    props = "property float x\nproperty float y\nproperty float z\n"
    path.write_bytes(f"ply\nformat {fmt} 1.0\nelement vertex {claimed}\n{props}end_header\n".encode() + body)
    return path


CLOUDS = {
    "npz-claims-1e12": (lambda p: _npz_claiming(p / "c.npz", (10**12, 3), bytes(240)), "1,000,000,000,000 points"),
    "npz-truncated": (lambda p: _npz_claiming(p / "c.npz", (1000, 3), bytes(240)), "truncated"),
    "npz-complex": (lambda p: _npz_claiming(p / "c.npz", (2, 3), bytes(96), "<c16"), "real numbers"),
    "npz-object": (lambda p: _npz_claiming(p / "c.npz", (2, 3), bytes(48), "|O"), "real numbers"),
    "npy-as-npz": (
        lambda p: np.save(p / "c.npz.npy", np.zeros((3, 3))) or (p / "c.npz.npy").rename(p / "c.npz"),
        ".npy",
    ),
    "ply-ascii-claims-1e12": (lambda p: _ply(p / "c.ply", 10**12, b"0 0 0\n1 1 1\n"), "1,000,000,000,000 points"),
    "ply-binary-truncated": (
        lambda p: _ply(p / "c.ply", 1000, bytes(36), "binary_little_endian"),
        "truncated: its header claims 1,000 vertices",
    ),
    "ply-ascii-truncated": (lambda p: _ply(p / "c.ply", 5000, b"0 0 0\n"), "truncated"),
    "ply-negative": (lambda p: _ply(p / "c.ply", -5, b"0 0 0\n"), "count -5"),
    "fifo": (lambda p: _fifo(p / "c.npz"), "FIFO (named pipe)"),
}


@pytest.mark.parametrize("case", sorted(CLOUDS))
def test_a_point_cloud_is_checked_before_it_is_read(case, problem_dict, tmp_path, capsys):
    CLOUDS[case][0](tmp_path)
    name = next(p.name for p in tmp_path.iterdir() if p.name.startswith("c."))
    cloud = {"name": "cloud", "type": "pointcloud", "path": name, "radius": 0.005}
    path = _with_obstacle(problem_dict, tmp_path, cloud)
    _refused(["plan", "--problem", str(path)], capsys, str(path), name, CLOUDS[case][1])


def test_a_compressed_cloud_of_too_many_points_is_refused_without_inflating_it(problem_dict, tmp_path, capsys):
    _zeros_npz(tmp_path / "c.npz", MAX_POINTS + 1)
    assert (tmp_path / "c.npz").stat().st_size < 2_000_000  # 240 MB of zeros
    cloud = {"name": "cloud", "type": "pointcloud", "path": "c.npz", "radius": 0.005}
    path = _with_obstacle(problem_dict, tmp_path, cloud)
    started = time.process_time()
    with pytest.raises(ProblemFileError, match="MAX_POINTS"):
        planbench.load_problems(path)
    assert time.process_time() - started < 0.5  # inflating 240 MB alone takes longer
    _refused(["plan", "--problem", str(path)], capsys, f"holds {MAX_POINTS + 1:,} points, more than the {MAX_POINTS:,}")


def test_cover_is_the_same_per_cube_as_per_offset(monkeypatch):
    """Cubes of many grid cells are filled one cube at a time: the same cells as the offsets loop
    (which allocated (cube edge / cell)^3 offsets: 2.8 GiB for 10 m cubes on a 0.02 m grid)."""
    from scipy.spatial.transform import Rotation

    calls = []
    per_cube_fill = VoxelCloud._cover_per_cube
    monkeypatch.setattr(VoxelCloud, "_cover_per_cube", lambda self, *a: calls.append(1) or per_cube_fill(self, *a))
    rng = np.random.default_rng(3)
    for rotated in (False, True):
        cloud = VoxelCloud.from_points(rng.uniform(-0.3, 0.3, size=(15, 3)), 0.13)
        q = rng.normal(size=4) if rotated else np.array([0, 0, 0, 1.0])
        R = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
        args = (R, np.array([0.01, -0.02, 0.03]), np.array([-0.6, -0.55, -0.5]), 0.011, [3, 0, 5], [100, 90, 95])
        per_cube = cloud.cover(*args)
        assert len(calls) == 1 + rotated  # 12 cells per cube edge: the per-cube path
        assert per_cube.sum() > 1000 and np.array_equal(per_cube, _cover_by_offsets(cloud, *args))


def _cover_by_offsets(cloud, R, position, origin, resolution, i0, i1):  # noqa: ANN001, ANN202
    """VoxelCloud.cover's offsets loop, whatever the cubes' size (the reference)."""
    import itertools

    from planbench.geometry.overlap import cubes_overlap_boxes

    i0, i1 = np.asarray(i0), np.asarray(i1)
    out, h = np.zeros(tuple(i1 - i0)), 0.5 * cloud.cell
    centres = cloud.centres @ R.T + position
    half = np.abs(R) @ np.full(3, h)
    lo = np.floor((centres - half - origin) / resolution + 1e-9).astype(np.int64)
    hi = np.ceil((centres + half - origin) / resolution - 1e-9).astype(np.int64)
    aligned = bool(np.allclose(R, np.eye(3), atol=1e-12))
    for off in itertools.product(range(int((hi - lo).max())), repeat=3):
        idx = lo + np.array(off)
        keep = np.all((idx < hi) & (idx >= i0) & (idx < i1), axis=1)
        idx = idx[keep]
        if not aligned and len(idx):
            grid_centres = origin + (idx + 0.5) * resolution
            idx = idx[cubes_overlap_boxes(grid_centres, 0.5 * resolution, centres[keep], R, np.full(3, h), 1e-9)]
        out[tuple((idx - i0).T)] = 1.0
    return out


# -- grids and kernels ---------------------------------------------------------------------------------------


def test_a_grid_past_the_cell_limit_is_refused_before_allocating():
    with pytest.raises(ResourceLimitError, match="MAX_GRID_CELLS") as info:
        OccupancyGrid.empty(np.zeros(3), np.full(3, 1e9), 0.02)
    assert "1.25e+32 cells" in str(info.value) and "0.02 m per cell" in str(info.value)
    side = int(round(MAX_GRID_CELLS ** (1 / 3)))
    assert np.prod(grid_shape(np.zeros(3), np.full(3, side * 0.02), 0.02)) <= MAX_GRID_CELLS


@pytest.mark.parametrize(
    "args, needle",
    [
        (["field", "--resolution", "0.001"], "MAX_GRID_CELLS"),
        (["field", "--resolution", "1e-5"], "MAX_KERNEL_CELLS"),
        (["field", "--reach", "1e6"], "MAX_KERNEL_CELLS"),
        (["field", "--slice", "z"], "axis=value"),
        (["field", "--outside", "2"], "--outside"),
        (["kernel", "--resolution", "1e-9"], "MAX_KERNEL_CELLS"),
        (["kernel", "--width", "1e6"], "MAX_KERNEL_CELLS"),
        (["kernel", "--profile", "all", "--resolution", "1e-9"], "MAX_KERNEL_CELLS"),
    ],
    ids=lambda x: " ".join(x) if isinstance(x, list) else None,
)
def test_field_and_kernel_settings_past_the_limits_are_named(args, needle, tmp_path, capsys):
    _refused([*args, "--out", str(tmp_path / "f.png")], capsys, needle)
    assert not (tmp_path / "f.png").exists()


def test_a_far_obstacle_makes_the_field_grid_too_large(problem_dict, tmp_path, capsys):
    far = {"name": "far", "type": "box", "size": [0.1, 0.1, 0.1], "position": [1e9, 1e9, 1e9]}
    path = _with_obstacle(problem_dict, tmp_path, far)
    _refused(["field", "--problem", str(path), "--out", str(tmp_path / "f.png")], capsys, "occupancy grid", "cells")


# -- scenarios ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "sensing, needle",
    [
        ({"model": "depth", "cameras": [{"width": 1.5}]}, "whole number of pixels"),
        ({"model": "depth", "cameras": [{"width": 100_000, "height": 100_000}]}, "MAX_CAMERA_PIXELS"),
        ({"model": "truth", "resolution": 1e-6}, "MAX_GRID_CELLS"),
        ({"model": "truth", "rate": 1e12}, "sensor frames, more than the 1,000,000"),
        (
            {"control_rate": 1e12},
            "control ticks, more than the 1,000,000 of a run (planbench.reactive.scenario.MAX_TICKS)",
        ),
    ],
    ids=["float-width", "huge-camera", "tiny-resolution", "sensor-rate", "control-rate"],
)
def test_a_scenario_that_would_allocate_without_bound_is_named(sensing, needle, tmp_path, capsys):
    from planbench.reactive.sets import load_scenarios

    d = load_scenarios("dynamic-smoke")[0].to_dict()
    change = sensing if "control_rate" in sensing else {"sensing": sensing}
    (tmp_path / "sc.json").write_text(json.dumps({**d, **change}))
    (tmp_path / "dyn.toml").write_text(
        f'[suite]\nname = "d"\nscenarios = ["{tmp_path / "sc.json"}"]\n[[controllers]]\ncontroller = "matrix-field"\n'
    )
    out = tmp_path / "r.db"
    _refused(["bench", "--suite", str(tmp_path / "dyn.toml"), "--out", str(out)], capsys, "sc.json", needle)
    assert not out.exists()


# -- arguments ----------------------------------------------------------------------------------------------


def test_time_limits_the_timers_cannot_take_are_refused(tmp_path, capsys):
    _refused(["plan", "--problem", "mbm:box/0001", "--time-limit", "1e308"], capsys, "--time-limit", "at most 1e+06")
    _refused(["check", "straight-line", "--timeout", "1e308"], capsys, "--timeout", "at most 1e+06")
    suite = tmp_path / "s.toml"
    suite.write_text('[suite]\nname = "s"\nproblems = ["mbm:box/0001"]\ngrace = 1e300\n[[planners]]\nplanner = "p"\n')
    _refused(["bench", "--suite", str(suite), "--out", str(tmp_path / "r.db")], capsys, "grace", "at most")


def test_bench_field_settings_are_checked_before_timing(capsys):
    _refused(["bench-field", "--quick", "--points", "-1"], capsys, "--points")
    _refused(["bench-field", "--sizes", "100000"], capsys, "--sizes")
    _refused(["bench-field", "--quick", "--budget", "nan"], capsys, "--budget")


def test_check_of_an_unknown_controller_exits_2(capsys):
    _refused(["check", "nope", "--controller"], capsys, "unknown controller 'nope'")


@pytest.mark.parametrize(
    "args",
    [
        ["--families", "nope"],
        ["-n", "-1"],
        ["--seed", "-1", "-n", "1"],
        ["--solvability", "nan"],
        ["--solvability", "1"],
    ],
    ids=lambda a: " ".join(a),
)
def test_the_generate_tool_names_bad_arguments(args, tmp_path, capsys):
    from planbench.problems.generators import main as generate

    assert generate(["--out", str(tmp_path / "gen"), *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("python -m planbench.problems.generate: error: ") and "Traceback" not in err


# -- outputs ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("results") / "r.db"
    with ResultsDB(path) as db:
        db.put_suite("s", {"planners": []}, "{}")
        for i in range(2):
            rec = failure_record("timeout", "killed")
            rec["path"] = np.random.default_rng(i).normal(size=(10, 7))
            fields = dict(suite="s", problem=f"mbm:box/{i + 1:04d}", family="box", planner="p", seed=0)
            db.add_run({**fields, "planner_name": "p", "settings": {}}, rec)
    return path


def test_outputs_that_are_folders_or_unread_fifos_are_refused_before_the_work(results, tmp_path, capsys):
    folder, fifo = tmp_path / "out", _fifo(tmp_path / "fifo")
    folder.mkdir()
    for option, out in (("--json", fifo), ("--replay", folder), ("--json", folder)):
        started = time.monotonic()
        _refused(["plan", "--problem", "mbm:box/0001", option, str(out)], capsys, str(out))
        assert time.monotonic() - started < 5  # before planning
    _refused(["replay", str(results), "--run", "1", "--out", str(folder)], capsys, "is a folder")
    _refused(["report", str(results), "--csv", str(fifo)], capsys, "FIFO (named pipe) that no process reads")
    _refused(["export", str(results), "--format", "csv", "--out", str(fifo)], capsys, "FIFO")
    _refused(["field", "--out", str(folder)], capsys, "is a folder")


def test_a_fifo_with_a_reader_is_a_fine_output(results, tmp_path, capsys):
    fifo = _fifo(tmp_path / "fifo")
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    time.sleep(0.2)
    assert main(["export", str(results), "--format", "csv", "--out", str(fifo)]) == 0
    reader.join(10)
    assert got and got[0].count(b"\n") == 3  # header and two runs


# -- results files damaged inside -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "sql, needle",
    [
        ("UPDATE runs SET path = x'deadbeef'", "its path is not a readable array"),
        ("UPDATE runs SET path = ?", "claims a float64 array of shape (1000000000000, 7)"),
        ("UPDATE runs SET planning_time = 'slow'", "column planning_time holds 'slow', not a number"),
    ],
    ids=["garbage-blob", "blob-claims-50-TiB", "text-in-a-number-column"],
)
def test_damaged_values_in_a_results_file_are_named(sql, needle, results, tmp_path, capsys):
    db = tmp_path / "r.db"
    db.write_bytes(results.read_bytes())
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<f8", "fortran_order": False, "shape": (10**12, 7)})
    conn = sqlite3.connect(db)
    conn.execute(sql, (head.getvalue(),) if "?" in sql else ())
    conn.commit()
    conn.close()
    _refused(["export", str(db), "--format", "csv", "--paths", "--out", str(tmp_path / "e.csv")], capsys, needle)
    _refused(["replay", str(db), "--run", "1", "--out", str(tmp_path / "r.html")], capsys, needle)


def test_suite_settings_that_are_not_json_are_named(results, tmp_path, capsys):
    db = tmp_path / "r.db"
    db.write_bytes(results.read_bytes())
    conn = sqlite3.connect(db)
    conn.execute("UPDATE suites SET settings = '[1'")
    conn.commit()
    conn.close()
    _refused(["report", str(db), "--html", str(tmp_path / "r.html")], capsys, "suite 's'", "not JSON")


# -- Ray cluster addresses -------------------------------------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Server:
    """A TCP server on the loopback that accepts and then says nothing, or answers an HTTP/2
    greeting with a SETTINGS frame and nothing more (a port that is not Ray, but speaks gRPC)."""

    def __init__(self, answer: bytes = b"") -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.port = int(self.sock.getsockname()[1])
        self.answer = answer
        self.conns: list[socket.socket] = []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            if self.answer:
                conn.sendall(self.answer)

    def close(self) -> None:
        for c in self.conns:
            c.close()
        self.sock.close()


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


_SERVER_SCRIPT = """
import socket, sys
answer = bytes.fromhex(sys.argv[1])
sock = socket.socket()
sock.bind(("127.0.0.1", 0))
sock.listen(8)
print(sock.getsockname()[1], flush=True)
conns = []
while True:
    conn, _ = sock.accept()
    conns.append(conn)
    if answer:
        conn.sendall(answer)
    print("accepted", flush=True)
"""


class _ServerProcess:
    """:class:`_Server` in a process of its own, which says on its standard output when it has
    accepted a connection (and answered it)."""

    def __init__(self, answer: bytes = b"") -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _SERVER_SCRIPT, answer.hex()], stdout=subprocess.PIPE, text=True
        )
        assert self.proc.stdout is not None
        self.port = int(self.proc.stdout.readline())

    def wait_for_connection(self, client: subprocess.Popen, timeout: float) -> None:
        """Return once the server has accepted a connection; fail if ``client`` ends first."""
        assert self.proc.stdout is not None
        with selectors.DefaultSelector() as sel:
            sel.register(self.proc.stdout, selectors.EVENT_READ)
            deadline = time.monotonic() + timeout
            while not sel.select(0.05):
                assert client.poll() is None, client.stderr.read() if client.stderr else "the command ended"
                assert time.monotonic() < deadline, f"no connection within {timeout:g} s"
        assert self.proc.stdout.readline().strip() == "accepted"

    def close(self) -> None:
        self.proc.kill()
        self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def test_cluster_addresses_are_parsed_without_ray(monkeypatch):
    from planbench.bench.ray_executor import cluster_endpoint
    from planbench.errors import InvalidConfigError

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    assert cluster_endpoint("10.0.0.5:6379") == ("10.0.0.5", 6379)
    assert cluster_endpoint("ray://head:10001") == ("head", 10001)
    assert cluster_endpoint("ray://head") == ("head", 10001)
    assert cluster_endpoint("[::1]:6379") == ("::1", 6379)
    assert cluster_endpoint("auto") is None and cluster_endpoint(None) is None and cluster_endpoint("local") is None
    monkeypatch.setenv("RAY_ADDRESS", "h:7000")
    assert cluster_endpoint("auto") == ("h", 7000)
    for bad, needle in (("garbage", "no port"), ("h:99999", "1 to 65535"), ("h:abc", "1 to 65535"), (":::", "IPv6")):
        with pytest.raises(InvalidConfigError, match=needle):
            cluster_endpoint(bad)


def test_unreachable_addresses_are_named_within_seconds_without_ray():
    from planbench.bench.ray_executor import RayClusterUnreachableError, check_reachable

    port = _free_port()
    with pytest.raises(RayClusterUnreachableError, match=f"127.0.0.1:{port} refused the connection"):
        check_reachable(f"127.0.0.1:{port}", timeout=1.0)
    silent = _Server()
    try:
        started = time.monotonic()
        with pytest.raises(RayClusterUnreachableError, match="did not answer within 0.5 s"):
            check_reachable(f"127.0.0.1:{silent.port}", timeout=0.5)
        assert time.monotonic() - started < 2
    finally:
        silent.close()
    http = _Server(b"HTTP/1.1 400 Bad Request\r\n\r\n")
    try:
        with pytest.raises(RayClusterUnreachableError, match="not as a Ray cluster"):
            check_reachable(f"127.0.0.1:{http.port}", timeout=1.0)
    finally:
        http.close()
    grpc = _Server(b"\x00\x00\x00\x04\x00\x00\x00\x00\x00")
    try:
        check_reachable(f"127.0.0.1:{grpc.port}", timeout=1.0)  # looks like a gRPC server: Ray's to judge
    finally:
        grpc.close()


def test_the_cli_names_an_unreachable_cluster(tmp_path, capsys):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'planbench[ray]')")
    port = _free_port()
    args = ["bench", "--executor", "ray", "--address", f"127.0.0.1:{port}", "--problems", "mbm:box/0001"]
    started = time.monotonic()
    _refused([*args, "--out", str(tmp_path / "r.db")], capsys, "cannot connect to the Ray cluster", "refused")
    assert time.monotonic() - started < 10 and not (tmp_path / "r.db").exists()


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS.parent), os.environ.get("PYTHONPATH", "")]))


@pytest.mark.slow
@pytest.mark.parametrize("server", ["silent", "grpc-but-not-ray"])
def test_ctrl_c_ends_a_connect_at_once(server, tmp_path):
    """Interrupted during the reachability check (a silent port) or inside ray.init (a port that
    answers the gRPC greeting, so Ray's own client waits on it): exit code 130 within a second."""
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'planbench[ray]')")
    # the fake server runs in its own process: a thread of this one can be held off for seconds by
    # the test process's own leftovers when the machine is loaded, so that it answers too late
    fake = _ServerProcess(b"" if server == "silent" else b"\x00\x00\x00\x04\x00\x00\x00\x00\x00")
    try:
        args = ["bench", "--executor", "ray", "--address", f"127.0.0.1:{fake.port}", "--problems", "mbm:box/0001"]
        # Ray alone would wait minutes; and it keeps 127.0.0.1 (not this host's address) with the variable at 0
        env = {**_env(), "RAY_NUM_REDIS_GET_RETRIES": "50", "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}
        proc = subprocess.Popen(
            [*PLANBENCH, *args, "--out", str(tmp_path / "r.db")],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            # Ctrl-C as at a terminal: a test run in a background job (`cmd &` in a script) passes
            # SIGINT on ignored, and Python then installs no KeyboardInterrupt for it
            preexec_fn=_default_sigint,
        )
        # into the wait: the command connects once its imports are done (about 2 s on a quiet
        # machine, several times that beside load), then Ray's client waits on the gRPC port; the
        # reachability check's own wait is 5 s, so the signal comes well inside it
        fake.wait_for_connection(proc, 120.0)
        time.sleep(0.5 if server == "silent" else 4.0)
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        os.kill(proc.pid, signal.SIGINT)
        started = time.monotonic()
        try:
            code = proc.wait(10)
        finally:
            if proc.poll() is None:
                proc.kill()
        err = proc.stderr.read() if proc.stderr else ""
        assert code == 130 and time.monotonic() - started < 2, f"exit {code}: {err[-2000:]}"
        assert "planbench: interrupted" in err
    finally:
        fake.close()

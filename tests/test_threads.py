"""Threads of the field kernels: small lazy calls run serially (same numbers as the parallel
kernel), and :func:`planbench.runtime.threads.limit_threads` sets what it says."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from planbench.field import Kernels, lazy_field
from planbench.geometry.occupancy import OccupancyGrid
from planbench.runtime import threads as field_threads
from planbench.runtime.backend import have_numba

NEEDS_NUMBA = pytest.mark.skipif(not have_numba(), reason="numba not installed")
RES = 0.05


def grid_and_points(dtype: str, n: int, seed: int = 0) -> tuple[OccupancyGrid, np.ndarray]:
    rng = np.random.default_rng(seed)
    grid = OccupancyGrid(
        (rng.random((24, 20, 18)) ** 3).astype(dtype), origin=[0.3, -0.2, 0.1], resolution=RES, outside=0.25
    )
    pts = rng.uniform(grid.origin - 0.3, grid.upper + 0.3, (n, 3))  # in, on and beyond the grid
    return grid, pts


def run_python(code: str) -> dict:
    """Run ``code`` in a fresh interpreter (thread pools are fixed per process); its last line
    of output is JSON."""
    proc = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=300, check=False
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_small_calls_are_under_the_threshold() -> None:
    # a planner's call: tens of control points, kernels of 15-25 cells
    assert field_threads.lazy_cells(30, 10) == 30 * 22**3
    assert field_threads.serial_lazy(30, 10)
    assert field_threads.serial_lazy(200, 12)
    assert field_threads.lazy_cells(2000, 10) > field_threads.SERIAL_MAX_CELLS


@NEEDS_NUMBA
@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("length", [3, 9, 21])
def test_serial_kernel_gives_the_parallel_numbers(dtype: str, length: int) -> None:
    from planbench.field import _compiled

    grid, pts = grid_and_points(dtype, 301, seed=length)
    kernels = Kernels.from_cells(length, max(3, length - 4), resolution=RES)
    along, across = kernels.factors(grid.data.dtype)
    par, ser = np.empty((len(pts), 3)), np.empty((len(pts), 3))
    args = (grid.data, grid.outside, grid.origin, grid.resolution, along, across, pts)
    _compiled.lazy_points(*args, par)
    _compiled.lazy_points_serial(*args, ser)
    tol = 1e-4 if dtype == "float32" else 1e-10
    assert np.abs(par).max() > 0
    np.testing.assert_allclose(ser, par, rtol=tol, atol=tol * np.abs(par).max())
    numpy_ref = lazy_field(grid, kernels, pts, backend="numpy")
    np.testing.assert_allclose(ser, numpy_ref, rtol=tol, atol=tol * np.abs(par).max())


@NEEDS_NUMBA
def test_threshold_routes_small_calls_to_the_serial_kernel(monkeypatch: pytest.MonkeyPatch) -> None:
    from planbench.field import _compiled

    grid, pts = grid_and_points("float64", 40)
    kernels = Kernels.from_cells(9, resolution=RES)
    expected = lazy_field(grid, kernels, pts, backend="numpy")
    called: list[str] = []
    for name in ("lazy_points", "lazy_points_serial"):
        real = getattr(_compiled, name)
        monkeypatch.setattr(_compiled, name, lambda *a, real=real, name=name: (called.append(name), real(*a))[1])
    small = lazy_field(grid, kernels, pts)
    assert called == ["lazy_points_serial"]
    np.testing.assert_allclose(small, expected, rtol=1e-10, atol=1e-12)
    called.clear()
    monkeypatch.setattr(field_threads, "SERIAL_MAX_CELLS", field_threads.lazy_cells(39, 4))
    big = lazy_field(grid, kernels, pts)  # 40 points: over the (lowered) threshold
    import numba

    assert called == (["lazy_points"] if numba.get_num_threads() > 1 else ["lazy_points_serial"])
    np.testing.assert_allclose(big, expected, rtol=1e-10, atol=1e-12)


@NEEDS_NUMBA
def test_serial_kernel_runs_on_the_calling_thread_only() -> None:
    # numba.get_thread_id() inside a kernel that, like lazy_points_serial, has no parallel loop;
    # and the parallel one on 2 threads uses both
    out = run_python("""
        import json, numpy as np, numba
        from numba import njit, prange

        @njit(parallel=True)
        def par(ids):
            for i in prange(ids.shape[0]):
                ids[i] = numba.get_thread_id()

        @njit
        def ser(ids):
            for i in prange(ids.shape[0]):  # prange in a serial function is range
                ids[i] = numba.get_thread_id()

        numba.set_num_threads(2)
        a, b = np.full(64, -1), np.full(64, -1)
        par(a); ser(b)
        print(json.dumps({"par": sorted(set(a.tolist())), "ser": sorted(set(b.tolist()))}))
    """)
    assert out["ser"] == [0]
    assert out["par"] == [0, 1]


@NEEDS_NUMBA
def test_limit_threads_before_numba_is_imported() -> None:
    # as in a worker: numpy (and its OpenBLAS, which reads its variable at load) already loaded
    out = run_python("""
        import json, sys, numpy as np
        from planbench.runtime.threads import limit_threads, thread_report
        before = thread_report()
        after = limit_threads(1, layer="workqueue")
        assert "numba" not in sys.modules
        import numba
        from numba import njit, prange

        @njit(parallel=True)
        def ids(out):
            for i in prange(out.shape[0]):
                out[i] = numba.get_thread_id()

        seen = np.full(256, -1)
        ids(seen)
        print(json.dumps({"before": before, "after": after, "threads": numba.get_num_threads(),
                          "seen": sorted(set(seen.tolist())), "final": thread_report()}))
    """)
    env = out["after"]["env"]
    for name in field_threads.THREAD_VARIABLES:
        assert env[name] == "1", name
    for name, value in field_threads.WAIT_VARIABLES.items():
        assert env[name] == value, name
    assert env["NUMBA_THREADING_LAYER"] == "workqueue"
    assert out["threads"] == 1 and out["seen"] == [0]
    assert out["final"]["numba_layer"] == "workqueue"
    assert out["final"]["numba_threads"] == 1
    # numpy's OpenBLAS was loaded before the call and is brought down to one thread
    if out["before"]["openblas"]:
        assert set(out["after"]["openblas"].values()) == {1}


@NEEDS_NUMBA
def test_limit_threads_after_numba_has_started() -> None:
    out = run_python("""
        import json, os, numpy as np, numba
        from numba import njit, prange
        from planbench.runtime.threads import limit_threads

        @njit(parallel=True)
        def ids(out):
            for i in prange(out.shape[0]):
                out[i] = numba.get_thread_id()

        numba.set_num_threads(2)
        ids(np.empty(8, np.int64))
        layer = numba.threading_layer()
        report = limit_threads(1)  # same layer: fine
        seen = np.full(256, -1)
        ids(seen)
        other = "workqueue" if layer != "workqueue" else "omp"
        try:
            limit_threads(1, layer=other)
            refused = ""
        except RuntimeError as exc:
            refused = str(exc)
        print(json.dumps({"report": report, "seen": sorted(set(seen.tolist())),
                          "refused": refused, "layer": layer}))
    """)
    assert out["report"]["numba_threads"] == 1
    assert out["report"]["numba_layer"] == out["layer"]
    assert out["seen"] == [0]
    assert "already" in out["refused"]


def test_limit_threads_without_numba() -> None:
    # the numpy/scipy fallback: nothing imports numba, the lazy field still works
    out = run_python("""
        import json, sys
        sys.modules["numba"] = None  # numba cannot be imported
        import numpy as np
        from planbench.field import Kernels, lazy_field
        from planbench.runtime.threads import limit_threads
        from planbench.geometry.occupancy import OccupancyGrid

        report = limit_threads(2)
        grid = OccupancyGrid(np.ones((6, 6, 6)), origin=[0, 0, 0], resolution=0.1)
        f = lazy_field(grid, Kernels.from_cells(3, resolution=0.1), [[-0.05, 0.3, 0.3]],
                       backend="numpy")
        print(json.dumps({"report": report, "f": f.tolist()}))
    """)
    assert out["report"]["numba_threads"] is None
    assert out["report"]["env"]["OMP_NUM_THREADS"] == "2"
    assert out["f"][0][0] != 0.0


def test_limit_threads_rejects_zero() -> None:
    with pytest.raises(ValueError, match="threads"):
        field_threads.limit_threads(0)

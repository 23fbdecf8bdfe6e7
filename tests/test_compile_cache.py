"""A first ``planbench plan`` on a cold numba cache computes with numpy and compiles in the
background (planbench.runtime.compile_cache); with the cache warm, or asked for numba, it compiles as before."""

from __future__ import annotations

import pytest

import planbench
from planbench.cli.compile import warm_up
from planbench.cli.main import main
from planbench.runtime import backend, compile_cache


@pytest.fixture
def cold(tmp_path, monkeypatch):
    """A marker directory of our own (the cache looks cold), the mechanism on, and the background
    compilation recorded instead of started."""
    monkeypatch.setenv("PLANBENCH_BACKGROUND_COMPILE", "1")
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)  # numba's own cache stays where it is
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    started: list[bool] = []
    monkeypatch.setattr(compile_cache, "warm_in_background", lambda: started.append(True))
    yield started
    backend.prefer(None)


def test_a_cold_cache_plans_with_numpy_and_starts_the_compilation(cold, capsys):
    assert not compile_cache.is_warm()
    assert main(["plan", "--problem", "mbm:box/0001", "--planner", "matrix-field", "--time-limit", "5"]) == 0
    assert cold == [True]
    assert backend.resolve("auto") == "numpy"
    assert not planbench.make_planner("matrix-field").use_numba
    assert "numba's cache is cold" in capsys.readouterr().err


def test_numba_by_name_compiles_in_the_foreground(cold):
    main(["plan", "--problem", "mbm:box/0001", "--planner", "matrix-field", "--set", "backend=numba"])
    assert cold == []
    assert backend.resolve("auto") == "numba"


def test_a_warm_cache_changes_nothing(cold, capsys, tmp_path):
    warm_up()  # numba's cache is warm in the test run: this loads it and writes the marker
    assert compile_cache.is_warm()
    assert compile_cache.marker_path().is_relative_to(tmp_path)
    main(["plan", "--problem", "mbm:box/0001", "--planner", "matrix-field"])
    assert cold == []
    assert backend.resolve("auto") == "numba"
    assert "cold" not in capsys.readouterr().err


def test_the_marker_follows_the_kernel_sources(cold, monkeypatch):
    before = compile_cache.marker_path()
    sources = compile_cache.kernel_sources()
    assert len(sources) == 5
    monkeypatch.setattr(compile_cache, "kernel_sources", lambda: sources[:1])
    assert compile_cache.marker_path() != before


def test_the_numpy_plan_is_the_numba_plan_to_rounding():
    problem = planbench.load_problems("mbm:box/0001")[0]
    a = planbench.plan(problem, "matrix-field", seed=0, time_limit=10, backend="numba")
    backend.prefer("numpy")
    try:
        b = planbench.plan(problem, "matrix-field", seed=0, time_limit=10)
    finally:
        backend.prefer(None)
    assert a.path.shape == b.path.shape
    assert abs(a.path - b.path).max() < 1e-6


def test_a_workers_private_cache_is_found_where_numba_looks_for_it(tmp_path):
    """The cache folder planbench computes without importing numba is numba's own."""
    from numba.core import caching

    for src in compile_cache.kernel_sources():
        assert compile_cache.cache_subpath(src) == caching._CacheLocator.get_suitable_cache_subpath(str(src))


def test_the_kernel_modules_are_the_ones_packages_declare():
    """The cache keys on what installed packages declare (entry points ``planbench.kernels``): the
    field's (the matrix field's and the calibrated field's), the IK loop's and the ``mppi``
    controller's kernels here; the core names no plugin module itself."""
    import inspect

    assert compile_cache.kernel_modules() == [
        "planbench.field._calibrated_compiled",
        "planbench.field._compiled",
        "planbench.geometry._compiled",
        "planbench_plugins.controllers._mppi_compiled",
        "planbench_plugins.ik_loop._compiled",
    ]
    names = [p.name for p in compile_cache.kernel_sources()]
    assert names == ["_calibrated_compiled.py", "_compiled.py", "_compiled.py", "_mppi_compiled.py", "_compiled.py"]
    assert "planbench_plugins" not in inspect.getsource(compile_cache)

import importlib.metadata
import sys
import textwrap

import numpy as np
import pytest

import planbench
from planbench import PlanResult, PlanStatus, Registry, register_planner
from planbench.errors import InvalidConfigError, PlannerUnavailableError, UnknownNameError


def install_fake_distribution(tmp_path, monkeypatch, name, entry_points, modules):
    """A package 'installed' the way pip leaves it: modules plus a .dist-info with entry points."""
    for module, source in modules.items():
        (tmp_path / f"{module}.py").write_text(textwrap.dedent(source))
    info = tmp_path / f"{name.replace('-', '_')}-1.2.3.dist-info"  # pip's normalized folder name
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 1.2.3\n")
    lines = "\n".join(f"{k} = {v}" for k, v in entry_points.items())
    (info / "entry_points.txt").write_text(f"[planbench.planners]\n{lines}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()


PLUGIN = """
    from dataclasses import dataclass
    import numpy as np
    from planbench import PlanResult, PlanStatus, Planner

    @dataclass(frozen=True)
    class HoldConfig:
        pass

    class HoldPlanner(Planner):
        name = "hold-still"
        Config = HoldConfig
        def plan(self, problem, *, time_limit, rng):
            return PlanResult(PlanStatus.TIMEOUT, problem.start[None, :])
"""


def test_entry_point_planner_from_another_package_is_found_lazily(tmp_path, monkeypatch):
    install_fake_distribution(
        tmp_path,
        monkeypatch,
        "planbench-hold",
        {
            "hold-still": "pb_hold_plugin:HoldPlanner",
            "needs-lib": "pb_missing_dep:Planner",
            "broken": "pb_broken:Planner",
        },
        {
            "pb_hold_plugin": PLUGIN,
            "pb_missing_dep": "import not_a_real_module_xyz\n",
            "pb_broken": "raise RuntimeError('boom at import')\n",
        },
    )
    registry = Registry()
    assert {"hold-still", "needs-lib", "broken", "straight-line"} <= set(registry.names())
    spec = registry.spec("hold-still")
    assert (spec.distribution, spec.version, spec.origin) == ("planbench-hold", "1.2.3", "entry point")
    assert "pb_hold_plugin" not in sys.modules  # not imported until used
    planner = registry.make("hold-still")
    assert "pb_hold_plugin" in sys.modules
    problem = planbench.load_problems("mbm:box/0001")[0]
    result = planbench.plan(problem, planner)
    assert result.status is PlanStatus.TIMEOUT

    with pytest.raises(PlannerUnavailableError, match="not_a_real_module_xyz") as info:
        registry.get("needs-lib")
    assert "pip install not_a_real_module_xyz" in str(info.value)
    assert not registry.spec("needs-lib").available
    with pytest.raises(PlannerUnavailableError, match="boom at import"):
        registry.get("broken")


def test_decorator_registration_into_an_isolated_registry():
    registry = Registry(discover=False)

    @register_planner(registry=registry)
    class Mine(planbench.Planner):
        name = "mine"

        def plan(self, problem, *, time_limit, rng):
            return PlanResult(PlanStatus.SUCCESS, problem.start[None, :])

    assert registry.names() == ["mine"]
    assert registry.get("mine") is Mine
    assert "mine" not in planbench.REGISTRY.names()
    with pytest.raises(ValueError, match="kebab-case"):
        registry.register(Mine, name="Not_Kebab")


def test_unknown_planner_suggests_close_names():
    with pytest.raises(UnknownNameError, match="Did you mean 'straight-line'"):
        planbench.REGISTRY.get("straight-lin")


def test_unknown_setting_lists_the_valid_ones():
    with pytest.raises(InvalidConfigError, match="timed"):
        planbench.make_planner("straight-line", speed=3)


def test_planner_that_raises_is_recorded_as_error_not_raised(free_problem):
    class Raises(planbench.Planner):
        name = "raises"

        def plan(self, problem, *, time_limit, rng):
            raise ZeroDivisionError("oops")

    result = planbench.plan(free_problem, Raises)
    assert result.status is PlanStatus.ERROR
    assert "ZeroDivisionError: oops" in result.message
    assert "Traceback" in result.info["traceback"]
    assert result.planning_time >= 0


def test_seeded_rng_reaches_the_planner(free_problem):
    class Random(planbench.Planner):
        name = "random"

        def plan(self, problem, *, time_limit, rng):
            return PlanResult(PlanStatus.TIMEOUT, np.stack([problem.start, problem.start + rng.normal(size=7) * 0.01]))

    a = planbench.plan(free_problem, Random, seed=3).path
    b = planbench.plan(free_problem, Random, seed=3).path
    c = planbench.plan(free_problem, Random, seed=4).path
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_family_variant_names_pass_the_variant_as_the_planner_setting():
    from planbench_plugins.ompl_planners import OMPLPlanner

    planner = planbench.make_planner("ompl:LBKPIECE1")
    assert isinstance(planner, OMPLPlanner) and planner.config.planner == "LBKPIECE1"
    with pytest.raises(UnknownNameError, match="RRTConnect"):
        planbench.make_planner("ompl:RRTConect")


def test_family_variant_names_a_preset_when_the_planner_declares_it():
    """``family:variant`` is the planner's preset ``variant`` (its settings, a setting given beside
    it wins) when the class declares one in ``presets``; otherwise the variant is the ``planner``
    setting, and a class without such a setting refuses it by name."""
    from dataclasses import dataclass

    registry = Registry(discover=False)

    @dataclass(frozen=True)
    class TunedConfig:
        speed: float = 1.0
        careful: bool = False

    @register_planner(registry=registry)
    class Tuned(planbench.Planner):
        name = "tuned"
        Config = TunedConfig
        presets = {"slow": {"speed": 0.25, "careful": True}}

        def plan(self, problem, *, time_limit, rng):
            return PlanResult(PlanStatus.TIMEOUT, problem.start[None, :])

    name, cls, implied = registry.resolve("tuned:slow")
    assert (name, cls, implied) == ("tuned:slow", Tuned, {"speed": 0.25, "careful": True})
    implied["speed"] = 9.0  # a copy: the class's preset is untouched
    assert Tuned.presets["slow"]["speed"] == 0.25
    assert registry.configure("tuned:slow").config == TunedConfig(speed=0.25, careful=True)
    assert registry.configure("tuned:slow", {"speed": 0.5}).config == TunedConfig(speed=0.5, careful=True)
    assert registry.configure("tuned", {}).config == TunedConfig()
    assert registry.resolve("tuned:fast")[2] == {"planner": "fast"}
    with pytest.raises(InvalidConfigError, match="planner"):
        registry.configure("tuned:fast")
    planner = planbench.make_planner("matrix-field:paper")
    assert planner.config.hierarchy == "nullspace" and planner.config.tool_repulsion_gain == 0.0

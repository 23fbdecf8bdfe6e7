"""One name, one plugin: a second, different plugin under a registered name is a DuplicatePluginError
naming both; the same plugin registered again (the same class, a module imported again, an entry
point's own module registering the class it names) is not an error."""

import sys
import types

import pytest
from test_registry import install_fake_distribution

import planbench
from planbench import PlanResult, PlanStatus, Registry, register_planner
from planbench.errors import DuplicatePluginError, PlanbenchError
from planbench.registry import register_controller
from planbench_plugins.straight_line import StraightLinePlanner

FAKE_MODULES = ("pb_self_registered", "pb_reexport", "pb_reexport_impl", "pb_two_names")
FAKE_MODULES += ("pb_dup_a", "pb_dup_b", "pb_package", "pb_package.impl")


@pytest.fixture(autouse=True)
def forget_fake_modules():
    yield
    for name in FAKE_MODULES:
        sys.modules.pop(name, None)


class Hold(planbench.Planner):
    name = "hold"

    def plan(self, problem, *, time_limit, rng):
        return PlanResult(PlanStatus.TIMEOUT, problem.start[None, :])


class OtherHold(Hold):
    name = "hold"


def test_a_second_plugin_under_a_name_is_an_error_naming_both_and_the_first_stays():
    registry = Registry(discover=False)
    registry.register(Hold)
    with pytest.raises(DuplicatePluginError) as info:
        registry.register(OtherHold)
    message = str(info.value)
    assert isinstance(info.value, PlanbenchError)
    assert message.startswith("planner 'hold' is registered twice: first by test_registry_duplicates:Hold")
    assert "then by test_registry_duplicates:OtherHold (registered in this process)" in message
    assert "give the new class another name" in message and "Registry(discover=False)" in message
    assert info.value.sources == (
        "test_registry_duplicates:Hold (registered in this process)",
        "test_registry_duplicates:OtherHold (registered in this process)",
    )
    assert registry.get("hold") is Hold and registry.names() == ["hold"]
    with pytest.raises(DuplicatePluginError, match="^planner 'hold' is registered twice"):
        registry.register("pb_somewhere:Else", name="hold")


def test_the_same_class_again_is_the_same_registration():
    registry = Registry(discover=False)
    first = register_planner(registry=registry)(Hold)
    assert register_planner(registry=registry)(Hold) is first is Hold
    assert registry.register(Hold) is registry.spec("hold")
    assert registry.register("test_registry_duplicates:Hold", name="hold") is registry.spec("hold")
    assert registry.names() == ["hold"] and registry.get("hold") is Hold


def test_a_module_imported_again_keeps_its_newest_class():
    """A notebook cell run twice, a module reloaded: a new class object of the same module and name."""
    registry = Registry(discover=False)
    code = "class Again(Hold):\n    name = 'again'\n"
    classes = []
    for _ in range(2):
        namespace = {"Hold": Hold, "__name__": "pb_again"}
        exec(code, namespace)
        classes.append(registry.register(namespace["Again"]).loaded)
    assert classes[0] is not classes[1]
    assert registry.get("again") is classes[1] and registry.names() == ["again"]


def test_the_built_in_planners_are_listed_once_and_registering_one_again_is_fine():
    registry = Registry()
    names = registry.names()
    assert len(names) == len(set(names)) and "straight-line" in names
    spec = registry.register(StraightLinePlanner)  # the class its entry point names
    assert spec is registry.spec("straight-line") and spec.origin == "entry point"
    assert spec.distribution == "planbench" and registry.names() == names
    assert planbench.REGISTRY.names().count("straight-line") == 1


def test_a_class_under_an_installed_plugins_name_is_an_error_naming_the_entry_point():
    registry = Registry()

    class Impostor(Hold):
        name = "straight-line"

    with pytest.raises(DuplicatePluginError) as info:
        register_planner(registry=registry)(Impostor)
    first, second = info.value.sources
    assert first.startswith(
        "entry point straight-line = planbench_plugins.straight_line:StraightLinePlanner of planbench "
    )
    assert second == f"{__name__}:{Impostor.__qualname__} (registered in this process)"
    assert registry.get("straight-line") is StraightLinePlanner


def test_a_controller_registered_twice_says_controller():
    registry = Registry(discover=False, group="planbench.controllers", kind="controller")
    register_controller(registry=registry)(Hold)
    with pytest.raises(DuplicatePluginError, match="^controller 'hold' is registered twice.*one controller"):
        register_controller(registry=registry)(OtherHold)


PLANNER = """
from planbench import Planner, PlanResult, PlanStatus, register_planner
from pb_dup_registry import REGISTRY


@register_planner(registry=REGISTRY)
class {cls}(Planner):
    name = "{name}"

    def plan(self, problem, *, time_limit, rng):
        return PlanResult(PlanStatus.TIMEOUT, problem.start[None, :])
"""


def test_an_entry_points_module_that_registers_its_own_class_loads_lazily(tmp_path, monkeypatch):
    """The module an entry point names may decorate its class too (for scripts that import it): the
    registration it makes while the registry imports it, or before, is the entry point's, not a
    duplicate; a re-exported class too; a different class under the entry point's name is one."""
    registry = Registry()
    monkeypatch.setitem(sys.modules, "pb_dup_registry", types.SimpleNamespace(REGISTRY=registry))
    install_fake_distribution(
        tmp_path,
        monkeypatch,
        "pb-self",
        {
            "self-registered": "pb_self_registered:SelfRegistered",
            "reexported": "pb_reexport:Reexported",
            "two-names": "pb_two_names:Named",
        },
        {
            "pb_self_registered": PLANNER.format(cls="SelfRegistered", name="self-registered"),
            "pb_reexport": "from pb_reexport_impl import Reexported\n",
            "pb_reexport_impl": PLANNER.format(cls="Reexported", name="reexported"),
            "pb_two_names": PLANNER.format(cls="Other", name="two-names") + "\n\nclass Named(Other):\n    pass\n",
        },
    )
    assert "pb_self_registered" not in sys.modules  # entry points are read, not imported
    cls = registry.get("self-registered")
    assert cls is sys.modules["pb_self_registered"].SelfRegistered
    assert registry.spec("self-registered").origin == "entry point"
    assert registry.get("reexported") is sys.modules["pb_reexport_impl"].Reexported
    with pytest.raises(DuplicatePluginError) as info:
        registry.get("two-names")
    assert info.value.sources == (
        "entry point two-names = pb_two_names:Named of pb-self 1.2.3",
        "pb_two_names:Other (registered in this process)",
    )
    assert not registry.spec("two-names").available
    assert "registered twice" in registry.spec("two-names").error  # what `planbench list` shows


def test_a_package_imported_before_its_entry_point_is_loaded_is_not_a_duplicate(tmp_path, monkeypatch):
    """A script imports the plugin's package first: the class its module registers is the one the
    entry point names through the package (``pb_package:Reexported``, defined in ``pb_package.impl``)."""
    registry = Registry()
    monkeypatch.setitem(sys.modules, "pb_dup_registry", types.SimpleNamespace(REGISTRY=registry))
    install_fake_distribution(tmp_path, monkeypatch, "pb-package", {"reexported": "pb_package:Reexported"}, {})
    (tmp_path / "pb_package").mkdir()
    (tmp_path / "pb_package" / "__init__.py").write_text("from pb_package.impl import Reexported\n")
    (tmp_path / "pb_package" / "impl.py").write_text(PLANNER.format(cls="Reexported", name="reexported"))
    registry.names()  # the entry point is known, not imported
    import pb_package

    assert registry.get("reexported") is pb_package.Reexported
    assert registry.spec("reexported").distribution == "pb-package"


def test_two_installed_distributions_with_one_name_are_an_error_when_it_is_used(tmp_path, monkeypatch):
    install_fake_distribution(tmp_path, monkeypatch, "pb-dup-a", {"twice": "pb_dup_a:Planner"}, {"pb_dup_a": ""})
    install_fake_distribution(tmp_path, monkeypatch, "pb-dup-b", {"twice": "pb_dup_b:Planner"}, {"pb_dup_b": ""})
    install_fake_distribution(
        tmp_path, monkeypatch, "pb-dup-c", {"straight-line": "planbench_plugins.straight_line:StraightLinePlanner"}, {}
    )
    registry = Registry()
    assert registry.names().count("twice") == 1  # still listed: `planbench list` shows why it cannot load
    assert registry.get("straight-line") is StraightLinePlanner  # the same entry point twice: one plugin
    with pytest.raises(DuplicatePluginError) as info:
        registry.get("twice")
    message = str(info.value)
    assert "entry point twice = pb_dup_a:Planner of pb-dup-a 1.2.3" in message
    assert "entry point twice = pb_dup_b:Planner of pb-dup-b 1.2.3" in message
    assert "pip uninstall pb-dup-a or pip uninstall pb-dup-b" in message
    assert "pb_dup_a" not in sys.modules and "pb_dup_b" not in sys.modules  # neither was imported
    assert not registry.spec("twice").available

"""Modules that moved into subpackages in 0.2 still import under their old names, with a
``DeprecationWarning`` that names the new place, as the very module (not a copy)."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

import planbench


@pytest.mark.parametrize("old", sorted(planbench.MOVED))
def test_an_old_name_imports_the_moved_module_with_a_warning(old: str) -> None:
    new = planbench.MOVED[old]
    assert old != new and new.startswith("planbench.") and old.count(".") == 1
    code = (
        "import importlib, warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        f"    old = importlib.import_module({old!r})\n"
        f"new = importlib.import_module({new!r})\n"
        "assert old is new, (old, new)\n"
        "messages = [str(w.message) for w in caught if w.category is DeprecationWarning]\n"
        f"assert any({new!r} in m for m in messages), messages\n"
    )
    # a fresh interpreter: this one may have imported the old name already (no second warning)
    subprocess.run([sys.executable, "-c", code], check=True)


def test_from_planbench_import_an_old_module_name() -> None:
    code = "import warnings; warnings.simplefilter('ignore')\nfrom planbench import collision, datasets\n"
    code += "assert collision.__name__ == 'planbench.checking.collision' and datasets.load_problems\n"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_a_name_that_never_existed_is_still_missing() -> None:
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("planbench.no_such_module")

"""Scenario sets by name, like problem sets: ``load_scenarios("dynamic")``.

Selectors:

- ``"dynamic"``: the 432 shipped scenarios (:mod:`planbench.reactive.generator`), the union of
  ``"dynamic-tune"`` (the scenarios of a third of the base problems, one per robot: tune a
  controller's defaults on these) and ``"dynamic-test"`` (the rest: measure on these);
  ``"dynamic-smoke"``: the 4 of the smoke suite.
- ``"dynamic:panda_crossing_fast_truth"`` (a family: robot, behaviour, speed, sensing), with
  ``/0001`` or ``/0001-0003`` for problems of the base set, and ``*`` in any part
  (``"dynamic:ur5_*_fast_*"``).
- ``"dynamic-test:*_depth"``: a family selector within one half of the split.
- A scenario file (``.json``) or a folder of them.
"""

from __future__ import annotations

import collections
import fnmatch
import functools
import json
from importlib import resources
from pathlib import Path
from typing import Any

from planbench.errors import PlanbenchError, ScenarioFileError, UnknownNameError
from planbench.problems.datasets import load_one
from planbench.reactive.scenario import Scenario

__all__ = ["SPLITS", "load_scenario", "load_scenarios", "scenario_names"]

SPLITS = ("dynamic-tune", "dynamic-test")
"""The shipped set's halves by base problem (:data:`planbench.reactive.generator.TUNE_PROBLEMS`)."""


@functools.lru_cache(maxsize=1)
def _shipped() -> dict[str, Any]:
    path = resources.files("planbench") / "data" / "scenarios" / "dynamic.json"
    return json.loads(path.read_text())  # type: ignore[no-any-return]


def scenario_names() -> list[str]:
    """Names of every shipped scenario, in the set's order."""
    return [d["name"] for d in _shipped()["scenarios"]]


def load_scenarios(selector: str | Path) -> list[Scenario]:
    """The scenarios ``selector`` names (module docstring), in a stable order."""
    text = str(selector)
    data = _shipped()
    if text in ("dynamic", "dynamic:*"):
        return [_build(d) for d in data["scenarios"]]
    if text == "dynamic-smoke":
        chosen = set(data["smoke"])
        return [_build(d) for d in data["scenarios"] if d["name"] in chosen]
    if text in SPLITS:
        split = text.removeprefix("dynamic-")
        return [_build(d) for d in data["scenarios"] if d["metadata"].get("split") == split]
    head, colon, rest = text.partition(":")
    if colon and head in ("dynamic", *SPLITS):
        family, _, rng = rest.partition("/")
        lo, hi = _range(rng, text)
        half = None if head == "dynamic" else head.removeprefix("dynamic-")
        found = []
        for d in data["scenarios"]:
            fam, index = d["name"].partition(":")[2].split("/")
            in_split = half is None or d["metadata"].get("split") == half
            if in_split and fnmatch.fnmatchcase(fam, family) and lo <= int(index) <= hi:
                found.append(_build(d))
        if not found:
            families = sorted({d["name"].partition(":")[2].split("/")[0] for d in data["scenarios"]})
            raise UnknownNameError(
                "scenario set", text, ["dynamic", *SPLITS, "dynamic-smoke", *(f"dynamic:{f}" for f in families)]
            )
        return found
    path = Path(text)
    if path.is_dir():
        files = sorted(path.glob("*.json"))
        if not files:
            raise PlanbenchError(f"{path}: folder holds no scenario .json files")
        return [Scenario.load(f) for f in files]
    if path.is_file() or (path.exists() and text.endswith(".json")):  # a FIFO or a device: named by Scenario.load
        return [Scenario.load(path)]
    raise UnknownNameError(
        "scenario set or file", text, ["dynamic", *SPLITS, "dynamic-smoke", "dynamic:<family>[/<range>]"]
    )


_ONE: collections.OrderedDict[str, Scenario] = collections.OrderedDict()


def load_scenario(ref: str) -> Scenario:
    """The one scenario ``ref`` names (a shipped name or a file), kept while among the last used
    (benchmark workers and validators load each run's scenario by reference)."""
    return load_one(_ONE, ref, load_scenarios, "scenario")  # type: ignore[no-any-return]


def _build(d: dict[str, Any]) -> Scenario:
    return Scenario.from_dict(d, f"dynamic set: {d.get('name')}")


def _range(text: str, selector: str) -> tuple[int, int]:
    if not text:
        return 1, 10**9
    lo, _, hi = text.partition("-")
    try:
        return int(lo), int(hi or lo)
    except ValueError:
        raise ScenarioFileError(selector, f"index range {text!r} must be N or N-M") from None

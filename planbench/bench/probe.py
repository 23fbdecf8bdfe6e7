"""Check a suite's planners in a throw-away process, so the benchmark's main process never imports
or constructs planner code.

Why: importing a plugin runs its module code, and building an instance runs its ``__init__``; a
plugin that patches numpy, json or planbench there would otherwise do so in the process that
checks results and writes the database. The probe is spawned, loads each planner, parses its
settings to the types of its ``Config`` (which needs the plugin's classes, hence here) and builds
it (its ``__init__`` may check settings too), and answers with data only
(:mod:`planbench.bench.wire`): whether it loaded (else the error's text and kind, and a bad
setting's data), the parsed settings, every setting of the built instance (its whole ``Config``,
defaults included: what the benchmark stores as each run's ``planner_config``), its module and
whether it asks for a fresh process per run.
It is contained like a worker: sandboxed to a scratch folder of its own
(:mod:`planbench.bench.sandbox`) and in a cgroup that is killed with it, so a plugin's import can
neither plant files for later processes nor leave a process behind.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing as mp
import os
import shutil
import tempfile
import time
from typing import Any

from planbench.bench import sandbox
from planbench.bench.procs import Cgroups, detach, join_cgroup, kill_group, limit_threads, thread_environment
from planbench.bench.wire import MAX_MESSAGE_BYTES, BadMessage, decode, encode
from planbench.errors import InvalidSettingError, PlanbenchError
from planbench.registry import CONTROLLERS, REGISTRY

__all__ = ["ProbeEntry", "probe_planners"]

PROBE_TIMEOUT = 300.0
"""[s] the probe may take to import and check every planner of a suite."""

ProbeEntry = tuple[str, dict[str, Any], dict[str, str]]
"""(planner, settings, command-line text settings) of one planner to check."""


def _probe_one(planner: str, settings: dict[str, Any], text: dict[str, str], kind: str = "planner") -> dict[str, Any]:
    try:
        registry = CONTROLLERS if kind == "controller" else REGISTRY
        setup = registry.configure(planner, settings, text=text)
        for key, value in setup.settings.items():
            try:
                json.dumps(value, allow_nan=True)
            except (TypeError, ValueError) as exc:
                expected = f"a benchmark stores settings as JSON data, and this value is not ({exc})"
                raise InvalidSettingError(setup.name, key, value, expected) from None
        instance = setup.build()  # its __init__ may check settings too (OMPL: the planner's name, its params)
    except InvalidSettingError as exc:
        return {"ok": False, "error": str(exc), "planbench_error": True, "setting_error": exc.to_data()}
    except PlanbenchError as exc:
        return {"ok": False, "error": str(exc), "planbench_error": True}
    except Exception as exc:  # a plugin's own failure: named, not a traceback
        return {"ok": False, "error": f"{type(exc).__name__}: {exc}", "planbench_error": False}
    module = getattr(setup.cls, "__module__", "")
    return {
        "ok": True,
        "module": module if isinstance(module, str) else "",
        "fresh_process": bool(getattr(setup.cls, "fresh_process", False)),
        "settings": setup.settings,
        "config": full_config(instance, setup.kwargs),
    }


def full_config(instance: Any, kwargs: dict[str, Any]) -> dict[str, Any]:
    """Every setting of a built planner: its ``config`` dataclass as a dict (defaults included, as
    its ``__init__`` left it), else the keyword arguments it was built with; values that are not
    JSON data as their ``repr``."""
    config = getattr(instance, "config", None)
    if dataclasses.is_dataclass(config) and not isinstance(config, type):
        values: dict[str, Any] = dataclasses.asdict(config)
    else:
        values = dict(kwargs)
    out = json.loads(json.dumps(values, allow_nan=True, default=repr))
    return out if isinstance(out, dict) else {}


def _probe_main(
    conn: Any,
    entries: list[ProbeEntry],
    parent_pid: int,
    kind: str = "planner",
    scratch: str = "",
    cgroup: str = "",
    writable: tuple[str, ...] = (),
) -> None:
    detach(parent_pid)
    join_cgroup(cgroup)
    if scratch:
        sandbox.enter(scratch, True, tuple(writable))
    limit_threads(1)
    answers = [_probe_one(planner, settings, text, kind) for planner, settings, text in entries]
    conn.send_bytes(encode({"type": "probe", "answers": answers}))


def probe_planners(
    entries: list[ProbeEntry], timeout: float = PROBE_TIMEOUT, kind: str = "planner"
) -> list[dict[str, Any]]:
    """For each ``(planner, settings, text settings)``, what :func:`_probe_one` found, in a spawned
    process: ``ok`` and, when true, the ``settings`` parsed to their fields' types (see
    :meth:`~planbench.registry.Registry.configure`), its full ``config`` (:func:`full_config`), the
    planner's ``module`` and ``fresh_process``;
    else the ``error``'s text (and ``setting_error``, an :class:`InvalidSettingError`'s data).

    The answers are the word of a process that ran plugin code: the caller checks what it uses.

    Raises :class:`PlanbenchError` when the probe dies, answers garbage, or takes over ``timeout`` s
    (a plugin whose import hangs). ``kind="controller"``: the entries are controllers.
    """
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=True)
    scratch = tempfile.mkdtemp(prefix="planbench-probe-")
    cgroups = Cgroups()
    cgroup = cgroups.make("probe")
    writable = sandbox.writable_folders()
    proc = ctx.Process(
        target=_probe_main,
        args=(child, entries, os.getpid(), kind, scratch, cgroup, writable),
        daemon=True,
        name="planbench-probe",
    )
    with thread_environment(1):
        proc.start()
    child.close()
    try:
        deadline = time.monotonic() + timeout
        while not parent.poll(0.1):
            if not proc.is_alive() and not parent.poll(0.1):
                raise PlanbenchError(f"loading the suite's planners ended the process with exit code {proc.exitcode}")
            if time.monotonic() > deadline:
                raise PlanbenchError(f"loading the suite's planners took more than {timeout:g} s")
        try:
            header, _ = decode(parent.recv_bytes(MAX_MESSAGE_BYTES))
        except (EOFError, OSError, BadMessage) as exc:
            raise PlanbenchError(f"loading the suite's planners gave no readable answer ({exc})") from exc
        answers = header.get("answers")
        if not (
            isinstance(answers, list) and len(answers) == len(entries) and all(isinstance(a, dict) for a in answers)
        ):
            raise PlanbenchError("loading the suite's planners gave a malformed answer")
        return answers
    finally:
        kill_group(proc.pid)
        cgroups.close()
        proc.join(5)
        parent.close()
        shutil.rmtree(scratch, ignore_errors=True)

"""Run a suite: expand it into runs, skip those already in the database, run the rest in isolated
worker processes and write each record as soon as it ends."""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from planbench.bench.db import ResultsDB
from planbench.bench.executors import Executor
from planbench.bench.kinds import expand, kind_of, registry_of
from planbench.bench.probe import probe_planners
from planbench.bench.records import Record, failure_record
from planbench.bench.runner import Runner
from planbench.bench.suite import PlannerEntry, Suite, load_suite, parse_seeds
from planbench.bench.task import RunTask
from planbench.bench.wire import BadField, clean_info
from planbench.errors import InvalidSettingError, PlanbenchError, UnstorableValueError

log = logging.getLogger(__name__)

__all__ = ["BenchmarkOutcome", "prepare", "run_benchmark", "select"]


@dataclass
class BenchmarkOutcome:
    """What a benchmark call did: runs planned in total, skipped (already done), run now, and the
    wall time [s] of the runs done now (worker start included)."""

    suite: str
    db_path: str
    total: int
    skipped: int
    ran: int
    wall_time: float
    skipped_planners: list[str]


def select(
    suite: Suite | str | Path,
    planners: Sequence[str] | None = None,
    problems: Sequence[str] | None = None,
    seeds: Any = None,
    time_limit: float | None = None,
    settings: Mapping[str, Any] | None = None,
    text_settings: Mapping[str, str] | None = None,
) -> Suite:
    """The suite narrowed or changed by command-line style options.

    ``planners``: labels of the suite, or registered names / ``"module:Attr"`` not in it (added
    with default settings); ``problems``: selectors replacing the suite's; ``seeds``: a count, a
    list or text (``"0,1,2"``, ``"5"``, ``"0-9"``); ``time_limit`` [s]; ``settings`` (values) and
    ``text_settings`` (as written on a command line, ``planbench bench --set``): planner settings
    given to every planner of the suite, over its own (each planner must have them; they are parsed
    to its ``Config``'s types when the benchmark checks its planners, before any run).
    """
    s = suite if isinstance(suite, Suite) else load_suite(suite)
    changes: dict[str, Any] = {}
    entries = list(s.planners)
    if planners:
        entries = []
        for name in planners:
            match = [p for p in s.planners if p.label == name]
            entries.append(match[0] if match else PlannerEntry(name.rpartition(":")[2], name))
    if settings or text_settings:
        entries = [
            replace(
                e,
                settings={**e.settings, **(settings or {})},
                text_settings={**e.text_settings, **(text_settings or {})},
            )
            for e in entries
        ]
    if entries != list(s.planners):
        changes["planners"] = tuple(entries)
    if problems:
        changes["problems"] = tuple(problems)
    if seeds is not None:
        changes["seeds"] = parse_seeds(seeds)
    if time_limit is not None:
        changes["time_limit"] = float(time_limit)
    return s.with_changes(**changes) if changes else s


def _check_planners(
    suite: Suite,
) -> tuple[list[PlannerEntry], list[str], dict[str, str], dict[str, dict[str, Any]]]:
    """Planners that can run, with their settings parsed to their types (checked here, before any
    worker starts), labels of optional planners skipped with the reason, each label's planner
    version, and each label's full configuration (every setting, defaults included; informational:
    the word of the probe, kept as JSON data within the size of a run's ``info``).

    The planners are loaded and built in a throw-away process (:mod:`planbench.bench.probe`): this
    process checks results and writes the database, so no planner code runs in it. A planner that
    cannot be used raises (an :class:`InvalidSettingError` for a bad setting), unless it is optional:
    then it is skipped, with the reason.
    """
    kind = kind_of(suite.kind).entry
    answers = probe_planners([(e.planner, dict(e.settings), dict(e.text_settings)) for e in suite.planners], kind=kind)
    usable, skipped, versions, configs = [], [], {}, {}
    for entry, answer in zip(suite.planners, answers, strict=True):
        where = suite.source + (f", planner label {entry.label!r}" if entry.label != entry.planner else "")
        if not answer.get("ok"):
            if entry.optional:
                skipped.append(f"{entry.label}: {answer.get('error')}")
                continue
            bad = _setting_error(answer, where)
            raise bad or PlanbenchError(f"{suite.source}: {kind} {entry.label!r}: {answer.get('error')}")
        versions[entry.label] = _version(entry.planner, answer, suite.kind)
        fresh = entry.fresh_process or answer.get("fresh_process") is True
        settings = answer.get("settings")
        given = {**entry.settings, **entry.text_settings}
        if not (isinstance(settings, dict) and set(settings) == set(given)):
            raise PlanbenchError(f"{suite.source}: planner {entry.label!r}: its settings came back malformed")
        usable.append(replace(entry, settings=settings, text_settings={}, fresh_process=fresh))
        try:
            configs[entry.label] = clean_info(answer.get("config", {}))
        except BadField:  # informational: a malformed answer stores none rather than failing the suite
            configs[entry.label] = {}
    return usable, skipped, versions, configs


def _setting_error(answer: dict[str, Any], where: str) -> InvalidSettingError | None:
    """The probe's bad setting as the error it was there (None when the answer holds none)."""
    data = answer.get("setting_error")
    try:
        return InvalidSettingError.from_data(data, where=where) if isinstance(data, dict) else None
    except TypeError:  # not an error's data: the answer's text is reported instead
        return None


def _version(planner: str, answer: dict[str, Any], kind: str = "static") -> str:
    """The distribution and version a registered planner (or controller) comes from (entry-point
    metadata, read without importing it), else the module the probe found it in."""
    family = planner.partition(":")[0]
    registry = registry_of(kind_of(kind))
    if family in registry.names():
        spec = registry.spec(family)
        return f"{spec.distribution} {spec.version}".strip()
    module = answer.get("module")
    return module if isinstance(module, str) else ""


def _complete(suite: Suite, db: ResultsDB, planners: list[PlannerEntry], refs: list[Any], stored: Any) -> bool:
    """Whether the database already holds every run of this suite, with the same settings: then
    running the same command again just reports them (nothing to resume, nothing lost)."""
    if stored is None or stored[1] != json.loads(suite.settings_json()):
        return False
    old = {p["label"]: (p["planner"], p["settings"]) for p in stored[0].get("planners", [])}
    if any(old.get(p.label) != (p.planner, p.settings) for p in planners):
        return False
    done = db.done_keys(suite.name)
    return all(
        (suite.name, ref.id, p.label, int(seed)) in done for p in planners for ref in refs for seed in suite.seeds
    )


def prepare(
    suite: Suite, db: ResultsDB, resume: bool = False, overwrite: bool = False
) -> tuple[list[RunTask], int, list[str]]:
    """Tasks still to run, how many are already done, and the skipped optional planners."""
    planners, skipped, versions, configs = _check_planners(suite)
    if not planners:
        raise PlanbenchError(f"{suite.source}: no planner of the suite can be loaded: " + "; ".join(skipped))
    checked = {p.label: p for p in planners}  # settings parsed: what is stored and compared
    suite = suite.with_changes(planners=tuple(checked.get(p.label, p) for p in suite.planners))
    refs = expand(kind_of(suite.kind), suite.problems)
    stored = db.suite_settings(suite.name)
    n_before = db.count(suite.name)
    if n_before and overwrite:
        db.delete_suite_runs(suite.name)
        n_before = 0
    elif n_before and not resume and not _complete(suite, db, planners, refs, stored):
        raise PlanbenchError(
            f"{db.path} already holds {n_before} runs of suite {suite.name!r}: pass --resume to run only the "
            "missing ones, --overwrite to replace them, or choose another --out"
        )
    if n_before and stored is not None:
        definition, settings = stored
        if settings != json.loads(suite.settings_json()):
            raise PlanbenchError(
                f"{db.path}: suite {suite.name!r} was run with settings {settings}, now {suite.settings_json()}; "
                "resuming would mix them: use another --out (or give the same settings, e.g. --memory-limit; "
                "results of another validator cannot be resumed)"
            )
        old = {p["label"]: (p["planner"], p["settings"]) for p in definition.get("planners", [])}
        for p in planners:
            if p.label in old and old[p.label] != (p.planner, p.settings):
                raise PlanbenchError(
                    f"{db.path}: planner {p.label!r} of suite {suite.name!r} was run as {old[p.label]}, now "
                    f"{(p.planner, p.settings)}; give it another label or use another --out"
                )
    definition = suite.to_dict()
    for p in definition["planners"]:
        p["config"] = configs.get(p["label"], {})
    if stored is not None and n_before:  # keep the union of planners run so far
        labels = {p.label for p in suite.planners}
        definition["planners"] = [p for p in stored[0]["planners"] if p["label"] not in labels] + list(
            definition["planners"]
        )
    db.put_suite(suite.name, definition, suite.settings_json())
    done = db.done_keys(suite.name)
    run_settings = json.loads(suite.settings_json())
    tasks = [
        RunTask(
            suite=suite.name,
            problem_id=ref.id,
            problem_ref=ref.ref,
            label=entry.label,
            planner=entry.planner,
            seed=int(seed),
            settings=entry.settings,
            family=ref.family,
            planner_version=versions.get(entry.label, ""),
            time_limit=float(suite.time_limit),
            grace=float(suite.grace),
            setup_timeout=float(suite.setup_timeout),
            validation_timeout=float(suite.validation_timeout),
            memory_limit=float(suite.memory_limit),
            validation=suite.validation,
            postprocess=suite.postprocess,
            fresh_process=entry.fresh_process,
            run_settings=run_settings,
            kind=suite.kind,
            timing=suite.timing,
        )
        for entry in planners
        for ref in refs
        for seed in suite.seeds
        if (suite.name, ref.id, entry.label, int(seed)) not in done
    ]
    # Interleave planners and problems so partial results (and the progress counts) are balanced.
    tasks.sort(key=lambda t: (t.seed, t.problem_id, t.label))
    n_done = len(refs) * len(suite.seeds) * len(planners) - len(tasks)
    return tasks, n_done, skipped


def run_benchmark(
    suite: Suite,
    out: str | Path,
    jobs: int | None = None,
    resume: bool = False,
    overwrite: bool = False,
    on_record: Callable[[RunTask, Record], None] | None = None,
    on_start: Callable[[int, int, list[str]], None] | None = None,
    executor: Executor | None = None,
) -> BenchmarkOutcome:
    """Run ``suite`` into the results database ``out`` (see :func:`prepare` for resume rules).

    ``executor`` runs the tasks (:mod:`planbench.bench.executors`; default: ``jobs`` local worker
    processes); whatever it is, this process writes every record.

    ``on_start(n_to_run, n_already_done, skipped_planners)`` and ``on_record(task, record)`` let the
    caller show progress; records are in the database before ``on_record`` is called.
    """
    created = not Path(out).exists()
    with ResultsDB(out) as db, db.lock_for_writing():
        try:
            tasks, n_done, skipped = prepare(suite, db, resume=resume, overwrite=overwrite)
        except PlanbenchError:
            if created:  # refused before any run: leave no empty results file behind
                _remove_results_file(db)
            raise
        if on_start is not None:
            on_start(len(tasks), n_done, skipped)
        stored = db.suite_settings(suite.name)
        configs = {p.get("label"): p.get("config") or {} for p in (stored[0].get("planners", []) if stored else [])}

        def write(task: RunTask, record: Record) -> None:
            fields = {
                "suite": task.suite,
                "problem": task.problem_id,
                "family": task.family,
                "planner": task.label,
                "seed": task.seed,
                "planner_name": task.planner,
                "planner_settings": task.settings,
                "planner_config": configs.get(task.label, {}),
                "planner_version": task.planner_version,
                "time_limit": task.time_limit,
                "settings": task.run_settings,
            }
            try:
                db.add_run(fields, record)
            except UnstorableValueError as exc:  # a last guard: the runner should have caught it
                record = failure_record("error", f"the run's record could not be stored: {exc.problem}")
                db.add_run(fields, record)
            if on_record is not None:
                on_record(task, record)

        t0 = time.perf_counter()
        (executor or Runner(jobs)).run(tasks, write)
        wall = time.perf_counter() - t0
        return BenchmarkOutcome(suite.name, str(db.path), len(tasks) + n_done, n_done, len(tasks), wall, skipped)


def _remove_results_file(db: ResultsDB) -> None:
    """Delete a results file this call created (and SQLite's side files), holding no runs."""
    if db.count():
        return
    db.close()
    for suffix in ("", "-wal", "-shm"):
        Path(f"{db.path}{suffix}").unlink(missing_ok=True)

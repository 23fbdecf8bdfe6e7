"""Benchmark suites: which problems, planners (with settings, under labels), seeds and limits.

A suite is a small TOML file (``planbench-suite/1``)::

    [suite]
    name = "my-suite"                 # the key under which results are stored
    description = "free text"
    problems = ["mbm:box/0001-0010", "mbm:cage", "my_problems/"]   # selectors, see load_problems
    seeds = [0, 1, 2]                 # a list, or a count n meaning 0 .. n-1 (default [0])
    time_limit = 2.0                  # [s] planning time per run (setup is timed apart)
    memory_limit = 8192               # [MiB] address space per worker process; 0 or "none": no limit
    setup_timeout = 60.0              # [s] hard limit on loading the problem and planner setup
    grace = 2.0                       # [s] slack past time_limit before a planning run is killed
    validation_timeout = 100.0        # [s] hard limit on validating one path
    postprocess = "none"              # every valid path post-processed alike: "none" or "shortcut"

    [validation]                      # optional: planbench.ValidationSettings fields
    required_clearance = 0.0          # [m] smallest distance allowed along a path

    [postprocess]                     # optional: planbench.bench.postprocess.PostprocessSettings fields
    attempts = 200                    # shortcut tries per path

    [[planners]]
    label = "mf-default"              # unique in the suite; defaults to the planner name
    planner = "matrix-field"          # a registered name or a "module:Attr" entry point
    settings = { }                    # the planner's Config fields, read as their types
    optional = false                  # true: skip (with a warning) when it cannot be loaded
    fresh_process = false             # true: every run in a new process (process-wide RNGs, e.g. OMPL)

A **closed-loop** suite (``planbench.reactive``) names scenarios and controllers instead::

    [suite]
    name = "my-dynamic"
    scenarios = ["dynamic:panda_*_fast_*", "my_scenarios/"]   # see planbench.load_scenarios
    timing = "measured"               # compute time charged: "measured", "ideal" (none)
    time_limit = 300.0                # [s] wall-clock limit of one whole run (the horizon is the scenario's)

    [[controllers]]
    controller = "matrix-field"       # a registered controller (entry-point group planbench.controllers)
    settings = { field_mode = "lazy" }

Inside, a closed-loop suite is the same :class:`Suite` with ``kind = "dynamic"``: ``problems``
holds the scenario selectors and ``planners`` the controller entries, so runs, isolation, the
results file, reports and exports are those of static runs.

The limits shown are examples; a suite that leaves one out gets :data:`DEFAULT_TIME_LIMIT`,
:data:`DEFAULT_MEMORY_LIMIT`, :data:`DEFAULT_SETUP_TIMEOUT`, :data:`DEFAULT_GRACE` or
:data:`DEFAULT_VALIDATION_TIMEOUT`. The same planner may appear several times under different labels
with different settings; each setting is parsed to the type of its ``Config`` field before any run
(``speed_max = "0.3"`` is 0.3, ``verify_path = "no"`` is False, ``"none"`` is None for an optional setting;
see :meth:`planbench.registry.Registry.configure`). The built-in suites (``smoke``, ``mbm``) ship in
``planbench/bench/suites``.

Seeds are integers with ``0 <= seed < 2**63`` (what numpy's ``default_rng`` and a SQLite INTEGER
both take), at most 1,000,000 of them.

``memory_limit`` defaults to :data:`DEFAULT_MEMORY_LIMIT` MiB, so that a planner that allocates
without bound becomes an ``error`` row (``MemoryError``) instead of taking the machine down; set it
in the suite or with ``planbench bench --memory-limit MIB`` (``none`` disables it). It caps the
worker's *virtual* address space (``RLIMIT_AS``), which is far more than the memory a run touches:
importing numpy, numba (LLVM), pinocchio, coal and OMPL and starting their thread pools reserves
address space that is never used. Measured on a fresh worker after one run on ``mbm:box/0001`` and
``mbm:bookshelf_tall/0001`` (VmPeak, the largest address space the process had, and VmHWM, its
largest resident memory): see :data:`DEFAULT_MEMORY_LIMIT` for the numbers and the margin.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from planbench.bench.postprocess import PostprocessSettingError, PostprocessSettings
from planbench.errors import DuplicateProblemError, InvalidConfigError, PlanbenchError, UnknownNameError
from planbench.files.inputs import InputFileError, read_text
from planbench.problem import Problem
from planbench.problems.datasets import load_problems
from planbench.validate import VALIDATOR, ValidationSettings

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "DEFAULT_GRACE",
    "DEFAULT_SETUP_TIMEOUT",
    "DEFAULT_TIME_LIMIT",
    "DEFAULT_VALIDATION_TIMEOUT",
    "PlannerEntry",
    "ProblemRef",
    "Suite",
    "SuiteFileError",
    "DEFAULT_MEMORY_LIMIT",
    "builtin_suites",
    "check_seconds",
    "check_seed",
    "expand_problems",
    "parse_memory_limit",
    "load_suite",
]

SUITE_FORMAT = "planbench-suite/1"

DEFAULT_TIME_LIMIT = 5.0
"""[s] planning time per run of a suite that sets no ``time_limit`` (``planbench.plan`` has its own,
:data:`planbench.harness.DEFAULT_TIME_LIMIT`)."""
DEFAULT_SETUP_TIMEOUT = 120.0
"""[s] hard limit on a run's setup (loading the problem, building the planner, its ``setup()``)."""
DEFAULT_GRACE = 5.0
"""[s] slack past ``time_limit`` before a planning run is killed."""
DEFAULT_VALIDATION_TIMEOUT = 300.0
"""[s] hard limit on validating one path."""

DEFAULT_MEMORY_LIMIT = 4096.0
"""[MiB] of address space per worker by default.

Measured VmPeak (address space) / VmHWM (resident) [MiB] of a fresh worker-like process (one
thread per pool, as benchmark workers run) after one run, on mbm:box/0001 and
mbm:bookshelf_tall/0001: after ``import planbench`` 101 / 30; straight-line 302-307 / 129-135;
matrix-field 592-681 / 277-368; matrix-field-qp 545-570 / 257-282; edt-field 575-595 / 258-269;
distance-field 554-560 / 236-243; ompl-rrtconnect, -bitstar, -prmstar, -kpiece, -rrtstar
452-464 / 137-143 (5 s runs). A long-lived matrix-field worker after 28 problems
(``mbm:*/0001-0004``): 732 / 414. 4096 MiB is more than 5x the largest, so no shipped planner
meets it, while a runaway allocation still ends as an ``error`` row long before a machine of
a few GiB per core runs out."""
MAX_SECONDS = 1e6
"""[s] The longest time limit or timeout accepted (11.6 days): the operating system's timers that
enforce them take no more (a longer one overflows them)."""
SEED_LIMIT = 2**63  # seeds are < 2**63: numpy's default_rng takes any, SQLite INTEGER is int64
MAX_SEEDS = 1_000_000


class SuiteFileError(PlanbenchError):
    """A suite file that cannot be used; names the file and what is wrong."""

    def __init__(self, source: str, problem: str) -> None:
        self.source = source
        self.problem = problem
        super().__init__(f"{source}: {problem}")


@dataclass(frozen=True)
class PlannerEntry:
    """One planner of a suite: ``planner`` (a registered name, ``family:variant`` or
    ``"module:Attr"``) with ``settings``, stored under ``label``.

    ``text_settings`` are settings as written on a command line (``planbench bench --set``), still
    to be read as their fields' types; the benchmark parses both (in its probe process, where the
    planner's ``Config`` may be imported) and stores the parsed ``settings`` only.
    """

    label: str
    planner: str
    settings: dict[str, Any] = field(default_factory=dict)
    optional: bool = False
    fresh_process: bool = False
    text_settings: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class ProblemRef:
    """A problem as workers find it: ``ref`` is what ``load_problems`` takes (an MBM id or a file)."""

    ref: str
    id: str
    family: str


@dataclass(frozen=True)
class Suite:
    """A benchmark definition (see the module docstring for the file format and units).
    ``kind``: ``"static"`` (problems and planners) or ``"dynamic"`` (scenarios and controllers, in
    ``problems`` and ``planners``); ``timing``: what a closed-loop run charges for compute time."""

    name: str
    problems: tuple[str, ...]
    planners: tuple[PlannerEntry, ...]
    seeds: tuple[int, ...] = (0,)
    time_limit: float = DEFAULT_TIME_LIMIT
    memory_limit: float = DEFAULT_MEMORY_LIMIT
    setup_timeout: float = DEFAULT_SETUP_TIMEOUT
    grace: float = DEFAULT_GRACE
    validation_timeout: float = DEFAULT_VALIDATION_TIMEOUT
    validation: dict[str, Any] = field(default_factory=dict)
    postprocess: dict[str, Any] = field(default_factory=dict)
    """The post-processing stage (:class:`planbench.bench.postprocess.PostprocessSettings` fields; empty:
    ``none``), applied by the harness to every planner's valid path alike."""
    description: str = ""
    source: str = "<python>"
    kind: str = "static"
    timing: str = "measured"

    def __post_init__(self) -> None:
        def bad(problem: str) -> SuiteFileError:
            return SuiteFileError(self.source, problem)

        if self.kind not in KINDS:
            raise bad(f"suite kind must be one of {KINDS}, got {self.kind!r}")
        if self.timing not in TIMINGS:
            raise bad(f"[suite] timing must be one of {TIMINGS}, got {self.timing!r}")

        if not self.name or not isinstance(self.name, str):
            raise bad("[suite] name must be a non-empty string")
        dynamic = self.kind == "dynamic"
        if not self.problems:
            if dynamic:
                raise bad("[suite] scenarios is empty: give at least one selector, e.g. 'dynamic-smoke'")
            raise bad("[suite] problems is empty: give at least one selector, e.g. 'mbm:box/0001'")
        if not self.planners:
            raise bad("no [[controllers]] given" if dynamic else "no [[planners]] given")
        if not self.seeds:
            raise bad("[suite] seeds is empty")
        for name in ("time_limit", "setup_timeout", "grace", "validation_timeout"):
            v = getattr(self, name)
            if not (_positive_number(v) and v <= MAX_SECONDS):
                raise bad(f"[suite] {name} must be a finite number > 0 [s], at most {MAX_SECONDS:g}, got {v!r}")
        m = self.memory_limit
        if not (_positive_number(m) or (isinstance(m, (int, float)) and not isinstance(m, bool) and m == 0)):
            raise bad(f'[suite] memory_limit must be a number of MiB > 0, or 0 / "none" for no limit, got {m!r}')
        for seed in self.seeds:
            check_seed(seed, self.source)
        labels = [p.label for p in self.planners]
        dupes = sorted({x for x in labels if labels.count(x) > 1})
        if dupes:
            raise bad(f"planner label(s) {dupes} appear more than once; give each entry its own label")
        try:
            ValidationSettings(**self.validation)
        except (TypeError, ValueError) as exc:
            known = [f.name for f in dataclasses.fields(ValidationSettings)]
            raise bad(f"[validation]: {exc} (fields: {', '.join(known)})") from exc
        if not isinstance(self.postprocess, dict):
            raise bad("[postprocess] must be a table")
        try:
            PostprocessSettings(**self.postprocess)
        except TypeError as exc:
            known = [f.name for f in dataclasses.fields(PostprocessSettings)]
            raise bad(f"[postprocess]: {exc} (fields: {', '.join(known)})") from exc
        except PostprocessSettingError as exc:
            raise bad(str(exc)) from exc
        if self.kind == "dynamic" and PostprocessSettings(**self.postprocess).active:
            raise bad("postprocess is for static suites (problems and [[planners]]), not closed-loop ones")

    @property
    def postprocess_settings(self) -> PostprocessSettings:
        return PostprocessSettings(**self.postprocess)

    def with_changes(self, **changes: Any) -> Suite:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for p in d["planners"]:
            if not p["text_settings"]:  # parsed into settings once the planners are checked
                del p["text_settings"]
        d["format"] = SUITE_FORMAT
        return d

    def settings_json(self) -> str:
        """The settings that change results (limits, validation and the validator's version, the
        post-processing stage when there is one), as canonical JSON."""
        keys = ("time_limit", "memory_limit", "setup_timeout", "grace", "validation_timeout", "validation")
        more: dict[str, Any] = {"kind": self.kind, "timing": self.timing} if self.kind == "dynamic" else {}
        stage = self.postprocess_settings
        if stage.active:  # absent for "none", so results written before the stage existed still resume
            more["postprocess"] = dataclasses.asdict(stage)
        return json.dumps({"validator": VALIDATOR, **{k: getattr(self, k) for k in keys}, **more}, sort_keys=True)

    def entry(self, label: str) -> PlannerEntry:
        for p in self.planners:
            if p.label == label:
                return p
        raise UnknownNameError("planner label in suite " + repr(self.name), label, [p.label for p in self.planners])


_SUITE_KEYS = {
    "name",
    "description",
    "problems",
    "seeds",
    "time_limit",
    "memory_limit",
    "setup_timeout",
    "grace",
    "validation_timeout",
    "format",
    "scenarios",
    "timing",
    "postprocess",
}
_PLANNER_KEYS = {"label", "planner", "settings", "optional", "fresh_process"}
KINDS = ("static", "dynamic")
TIMINGS = ("measured", "ideal")
DEFAULT_DYNAMIC_TIME_LIMIT = 300.0
"""[s] wall-clock limit of one closed-loop run when the suite gives none (a 10 s scenario at
100 Hz with depth sensing and certified ticks takes seconds to a minute)."""


def builtin_suites() -> dict[str, Path]:
    """Names of the suites shipped with planbench, and their files."""
    folder = resources.files("planbench.bench") / "suites"
    return {Path(str(f)).stem: Path(str(f)) for f in folder.iterdir() if str(f).endswith(".toml")}


def load_suite(name_or_path: str | Path) -> Suite:
    """A built-in suite by name (``smoke``, ``mbm``) or a suite TOML file."""
    text = str(name_or_path)
    builtins = builtin_suites()
    if text in builtins:
        return parse_suite(builtins[text].read_text(), source=f"built-in suite {text!r} ({builtins[text]})")
    path = Path(text)
    if path.is_file() or (path.exists() and not path.is_dir()):  # a FIFO or a device: named below
        try:
            content = read_text(path)
        except InputFileError as exc:
            raise SuiteFileError(str(path), exc.problem) from None
        suite = parse_suite(content, source=str(path))
        here = path.resolve().parent  # files a suite names are found next to it, wherever it runs
        return suite.with_changes(problems=tuple(_next_to(sel, here) for sel in suite.problems))
    if path.suffix in (".toml", ".tml") or "/" in text:
        raise SuiteFileError(text, "no such file")
    raise UnknownNameError("suite (built-in name or .toml file)", text, list(builtins))


def parse_suite(content: str, source: str = "<string>") -> Suite:
    """A :class:`Suite` from TOML text; errors name ``source`` and the offending key."""
    try:
        data = tomllib.loads(content)
    except tomllib.TOMLDecodeError as exc:
        raise SuiteFileError(source, f"not valid TOML: {exc}") from exc
    unknown_tables = set(data) - {"suite", "planners", "controllers", "validation", "postprocess"}
    if unknown_tables:
        raise SuiteFileError(
            source,
            f"unknown table(s) {sorted(unknown_tables)}; use [suite], [[planners]] (or [[controllers]]), "
            "[validation], [postprocess]",
        )
    head = data.get("suite")
    if not isinstance(head, dict):
        raise SuiteFileError(source, "missing [suite] table (name, problems, seeds, time_limit, ...)")
    unknown = set(head) - _SUITE_KEYS
    if unknown:
        raise SuiteFileError(source, f"[suite] has unknown key(s) {sorted(unknown)}; known: {sorted(_SUITE_KEYS)}")
    if head.get("format", SUITE_FORMAT) != SUITE_FORMAT:
        raise SuiteFileError(source, f"[suite] format {head['format']!r} is not {SUITE_FORMAT!r}")
    dynamic = "scenarios" in head or "controllers" in data
    if dynamic and ("problems" in head or "planners" in data):
        raise SuiteFileError(
            source, "a suite has either problems and [[planners]] or scenarios and [[controllers]], not both"
        )
    what, table, word = ("scenarios", "controllers", "controller") if dynamic else ("problems", "planners", "planner")
    problems = head.get(what, [])
    if isinstance(problems, str):
        problems = [problems]
    if not isinstance(problems, list) or not all(isinstance(p, str) for p in problems):
        raise SuiteFileError(source, f"[suite] {what} must be a list of selector strings")
    seeds = parse_seeds(head.get("seeds", [0]), source)
    planners_raw = data.get(table, [])
    if not isinstance(planners_raw, list):
        raise SuiteFileError(source, f"{table} must be an array of tables: [[{table}]]")
    known_keys = _PLANNER_KEYS - {"planner"} | {word} if dynamic else _PLANNER_KEYS
    planners = []
    for i, entry in enumerate(planners_raw, start=1):
        where = f"[[{table}]] entry {i}"
        if not isinstance(entry, dict):
            raise SuiteFileError(source, f"{where} is not a table")
        unknown = set(entry) - known_keys
        if unknown:
            raise SuiteFileError(source, f"{where} has unknown key(s) {sorted(unknown)}; known: {sorted(known_keys)}")
        if dynamic and word in entry:
            entry = {("planner" if k == word else k): v for k, v in entry.items()}
        if not isinstance(entry.get("planner"), str) or not entry["planner"]:
            raise SuiteFileError(source, f'{where} needs {word} = "<registered name or module:Attr>"')
        settings = entry.get("settings", {})
        if not isinstance(settings, dict):
            raise SuiteFileError(source, f"{where}: settings must be a table")
        label = entry.get("label", entry["planner"].rpartition(":")[2])
        planners.append(
            PlannerEntry(
                str(label),
                entry["planner"],
                dict(settings),
                bool(entry.get("optional", False)),
                bool(entry.get("fresh_process", False)),
            )
        )
    validation = data.get("validation", {})
    if not isinstance(validation, dict):
        raise SuiteFileError(source, "[validation] must be a table")
    kwargs = {k: head[k] for k in ("time_limit", "setup_timeout", "grace", "validation_timeout") if k in head}
    stage = data.get("postprocess", {})
    if not isinstance(stage, dict):
        raise SuiteFileError(source, "[postprocess] must be a table (its method is [suite] postprocess)")
    if "method" in stage:
        raise SuiteFileError(source, '[postprocess] method: give it as [suite] postprocess = "shortcut"')
    if "postprocess" in head:
        if not isinstance(head["postprocess"], str):
            raise SuiteFileError(
                source, f'[suite] postprocess must be "none" or "shortcut", got {head["postprocess"]!r}'
            )
        stage = {**stage, "method": head["postprocess"]}
    kwargs["postprocess"] = dict(stage)
    if dynamic:
        kwargs.update(kind="dynamic", timing=head.get("timing", "measured"))
        kwargs.setdefault("time_limit", DEFAULT_DYNAMIC_TIME_LIMIT)
    elif "timing" in head:
        raise SuiteFileError(source, "[suite] timing is for closed-loop suites (scenarios and [[controllers]])")
    if "memory_limit" in head:
        kwargs["memory_limit"] = parse_memory_limit(head["memory_limit"], f"{source}: [suite] memory_limit")
    return Suite(
        name=head.get("name", ""),
        description=str(head.get("description", "")),
        problems=tuple(problems),
        planners=tuple(planners),
        seeds=seeds,
        validation=dict(validation),
        source=source,
        **kwargs,
    )


def _next_to(selector: str, folder: Path) -> str:
    """``selector`` as the path of a file or folder next to the suite file when there is one there
    (a relative path in a suite is relative to the suite, not to where planbench runs)."""
    candidate = Path(selector)
    if ":" in selector or candidate.is_absolute() or not (folder / candidate).exists():
        return selector
    return str(folder / candidate)


def _positive_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def check_seconds(value: Any, what: str) -> float:
    """``value`` as seconds when it is a finite number > 0, else an error naming ``what``."""
    if not (_positive_number(value) and value <= MAX_SECONDS):
        raise InvalidConfigError(
            f"{what} must be a finite number of seconds > 0, at most {MAX_SECONDS:g}, got {value!r}"
        )
    return float(value)


def parse_memory_limit(value: Any, source: str = "--memory-limit") -> float:
    """MiB from a number, a numeric string, or ``"none"`` (0.0: no limit)."""
    if isinstance(value, str):
        text = value.strip().lower()
        if text in ("none", "0"):
            return 0.0
        try:
            value = float(text)
        except ValueError:
            value = text
    if _positive_number(value) or value == 0:
        return float(value)
    raise SuiteFileError(source, f'memory_limit must be a number of MiB > 0, or "none" for no limit, got {value!r}')


def check_seed(seed: int, source: str = "--seed") -> int:
    """``seed`` when ``0 <= seed < 2**63`` (numpy's default_rng and SQLite INTEGER both take it)."""
    if not 0 <= seed < SEED_LIMIT:
        raise SuiteFileError(source, f"seed {seed} is out of range: seeds are integers with 0 <= seed < 2**63")
    return seed


def parse_seeds(value: Any, source: str = "--seeds") -> tuple[int, ...]:
    """Seeds from a list of ints, a count ``n`` (0..n-1), or text ``"0,1,5"`` / ``"3"`` / ``"0-9"``."""
    if isinstance(value, str):
        text = value.strip()
        try:
            if "," in text:
                value = [int(x) for x in text.split(",") if x.strip()]
            elif "-" in text[1:]:
                lo_text, _, hi_text = text.partition("-")
                lo, hi = check_seed(int(lo_text), source), check_seed(int(hi_text), source)
                if hi < lo or hi - lo >= MAX_SEEDS:
                    raise SuiteFileError(source, f"seed range {text!r}: give lo-hi with lo <= hi, at most {MAX_SEEDS}")
                value = list(range(lo, hi + 1))
            else:
                value = int(text)
        except ValueError as exc:
            raise SuiteFileError(source, f"seeds {value!r}: use a count (3), a list (0,1,5) or a range (0-9)") from exc
    if isinstance(value, bool):
        raise SuiteFileError(source, "seeds must be a count or a list of integers")
    if isinstance(value, int):
        if not 1 <= value <= MAX_SEEDS:
            raise SuiteFileError(source, f"a seed count must be between 1 and {MAX_SEEDS}, got {value}")
        return tuple(range(value))
    if isinstance(value, list) and value and all(isinstance(s, int) and not isinstance(s, bool) for s in value):
        if len(set(value)) != len(value):
            raise SuiteFileError(source, f"seeds {value} repeat a value")
        if len(value) > MAX_SEEDS:
            raise SuiteFileError(source, f"{len(value)} seeds: at most {MAX_SEEDS}")
        for seed in value:
            check_seed(seed, source)
        return tuple(value)
    raise SuiteFileError(source, f"seeds must be a count or a non-empty list of integers, got {value!r}")


def expand_problems(selectors: tuple[str, ...] | list[str]) -> list[ProblemRef]:
    """The problems named by ``selectors``, in order, without repeats.

    The same problem selected twice (overlapping selectors) counts once; two *different* sources
    with one id raise :class:`DuplicateProblemError` naming both, since runs are keyed by the id
    and would otherwise be silently merged into one.
    """
    out: dict[str, ProblemRef] = {}
    for sel in selectors:
        path = Path(sel)
        if not sel.startswith("mbm") and (path.is_dir() or path.is_file() or (path.exists() and sel.endswith(".json"))):
            files = sorted(path.glob("*.json")) if path.is_dir() else [path]
            if not files:
                raise PlanbenchError(f"{path}: folder holds no problem .json files")
            for f in files:
                p = Problem.load(f)
                _add_ref(out, ProblemRef(str(f.resolve()), p.id, str(p.metadata.get("family", ""))))
        else:
            for p in load_problems(sel):
                _add_ref(out, ProblemRef(p.id, p.id, str(p.metadata.get("family", ""))))
    return list(out.values())


def expand_scenarios(selectors: tuple[str, ...] | list[str]) -> list[ProblemRef]:
    """The scenarios named by ``selectors`` (see :func:`planbench.reactive.sets.load_scenarios`), in
    order, without repeats, as references a worker loads them by (a shipped name or a file)."""
    from planbench.reactive.sets import load_scenarios

    out: dict[str, ProblemRef] = {}
    for sel in selectors:
        path = Path(sel)
        if path.is_dir() or path.is_file() or (path.exists() and sel.endswith(".json")):
            files = sorted(path.glob("*.json")) if path.is_dir() else [path]
            if not files:
                raise PlanbenchError(f"{path}: folder holds no scenario .json files")
            for f in files:
                s = load_scenarios(f)[0]
                _add_ref(out, ProblemRef(str(f.resolve()), s.name, str(s.metadata.get("family", ""))))
        else:
            for s in load_scenarios(sel):
                _add_ref(out, ProblemRef(s.name, s.name, str(s.metadata.get("family", ""))))
    return list(out.values())


def _add_ref(out: dict[str, ProblemRef], ref: ProblemRef) -> None:
    old = out.setdefault(ref.id, ref)
    if old.ref != ref.ref:
        raise DuplicateProblemError(ref.id, _source_text(old.ref), _source_text(ref.ref))


def _source_text(ref: str) -> str:
    return f"the built-in problem {ref}" if ref.startswith("mbm:") else ref

"""``planbench check-scenario FILE...``: prove scenarios solvable, each with a certificate stored in it.

A scenario's certificate (:mod:`planbench.reactive.certificate`) is a timed trajectory that solves
it, judged as a controller's run is. For each scenario of each file (a scenario file, or a set file
such as ``planbench/data/scenarios/dynamic.json``) the command verifies the certificate it holds;
where there is none, or it is refused, the space-time planner (:mod:`planbench.reactive.spacetime`)
searches one within ``--budget`` seconds, and ``--write`` (the default) stores it in the file.
Scenarios that differ only in their sensing, name or metadata share their geometry: one search
serves them all. Exit code 0 when every scenario has a certificate, 1 when one has none, 2 on bad
input (nothing searched).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from planbench.errors import PlanbenchError, ScenarioFileError
from planbench.files.inputs import InputFileError, check_writable, read_json
from planbench.reactive.certificate import Certificate
from planbench.reactive.scenario import Scenario

__all__ = ["add_commands"]

SET_FORMAT = "planbench-scenario-set/1"


def add_commands(subparsers: Any) -> None:
    """Add ``check-scenario`` to an argparse subparsers object."""
    p = subparsers.add_parser(
        "check-scenario",
        help="prove scenarios solvable: find (or verify) a certificate trajectory and store it in the file",
        description="For each scenario of each file (a scenario .json or a scenario set), verify the "
        "solvability certificate it holds, or search one with an omniscient space-time planner (it knows "
        "every obstacle's motion) and store it in the file. A certificate is judged exactly as a "
        "controller's run: every control tick certified against the moving geometry, the goal reached "
        "within the horizon, velocity and joint limits kept. Exit code 0: every scenario has one; 1: "
        "none was found for some within the budget; 2: bad input.",
    )
    p.add_argument("files", nargs="+", metavar="FILE", help="scenario files or scenario-set files (.json)")
    p.add_argument("--budget", type=float, default=60.0, help="[s] of search per scenario geometry")
    p.add_argument(
        "--replay",
        metavar="HTML",
        help="write a 3D replay of each certificate; with several scenarios, one page per scenario "
        "named HTML's stem, '-', the scenario's name",
    )
    p.add_argument(
        "--write",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="store new certificates in the files (--no-write: only say what was found)",
    )
    p.set_defaults(func=cmd_check_scenario)


@dataclass
class _Entry:
    """One scenario of a file: its JSON object (updated in place) and its parsed form."""

    file: Path
    data: dict[str, Any]
    scenario: Scenario


def cmd_check_scenario(args: argparse.Namespace) -> int:
    from planbench.bench.suite import check_seconds
    from planbench.reactive.solvability import verify_certificate
    from planbench.reactive.spacetime import SpaceTimeSettings, find_certificate

    budget = check_seconds(args.budget, "--budget")
    files = [Path(f) for f in args.files]
    loaded = [(path, *_read(path)) for path in files]  # every file read and parsed before any search
    entries = [e for _, _, found in loaded for e in found]
    if args.write:
        for path in files:
            check_writable(path, "scenario")
    pages = _pages(args.replay, entries) if args.replay else {}
    for out in pages.values():
        check_writable(out, "--replay")
    by_geometry: dict[str, Certificate] = {}
    changed: set[Path] = set()
    missing = 0
    for i, e in enumerate(entries):
        name = f"{e.file}: {e.scenario.name}"
        key = _geometry_key(e.data)
        cert = e.scenario.certificate
        if cert is not None:
            metrics = verify_certificate(e.scenario)
            if metrics.success:
                print(f"{name}: certificate verified (time to goal {metrics.time_to_goal:.2f} s)", flush=True)
                by_geometry.setdefault(key, cert)
                _replay(pages.get(i), e, cert)
                continue
            print(f"{name}: its certificate is refused ({metrics.failure}); searching a new one", flush=True)
        cert = by_geometry.get(key)
        if cert is not None and verify_certificate(e.scenario, cert).success:
            print(f"{name}: certificate of the same geometry verified (time to goal {cert.time_to_goal:.2f} s)")
        else:
            search = find_certificate(e.scenario, SpaceTimeSettings(budget=budget))
            if search.certificate is None:
                missing += 1
                print(f"{name}: NO certificate: {search.reason}", flush=True)
                continue
            cert = replace(search.certificate, budget=budget)
            by_geometry[key] = cert
            print(
                f"{name}: certificate found in {search.elapsed:.1f} s ({_paths(search.paths)}; time to goal "
                f"{cert.time_to_goal:.2f} s)",
                flush=True,
            )
        e.data["certificate"] = cert.to_dict()
        changed.add(e.file)
        _replay(pages.get(i), e, cert)
    if args.write:
        for path, data, _ in loaded:
            if path in changed:
                _write(path, data)
                print(f"certificates written to {path}")
    for out in pages.values():
        print(f"replay written to {out} (open it in a browser)")
    total = len(entries)
    print(f"{total - missing}/{total} scenarios have a certificate")
    return 0 if missing == 0 else 1


def _paths(n: int) -> str:
    return f"{n} path" + ("" if n == 1 else "s")


def _read(path: Path) -> tuple[dict[str, Any], list[_Entry]]:
    """The file's JSON and its scenarios (one, or a set's); a named error when either is bad."""
    try:
        data = read_json(path)
    except InputFileError as exc:
        raise ScenarioFileError(path, exc.problem) from None
    if isinstance(data, dict) and data.get("format") == SET_FORMAT:
        items = data.get("scenarios")
        if not isinstance(items, list) or not items:
            raise ScenarioFileError(path, "a scenario set needs a non-empty list 'scenarios'")
        found = [_entry(path, d, f"{path}: scenarios[{k}]") for k, d in enumerate(items)]
        return data, found
    return data, [_entry(path, data, str(path))]


def _entry(path: Path, d: Any, source: str) -> _Entry:
    scenario = Scenario.from_dict(d, source, path.parent)
    return _Entry(path, d, scenario)


def _geometry_key(d: dict[str, Any]) -> str:
    """What a certificate depends on: all but the sensing, name, metadata and certificate."""
    kept = {k: v for k, v in d.items() if k not in ("sensing", "name", "metadata", "certificate")}
    return json.dumps(kept, sort_keys=True)


def _pages(out: str, entries: list[_Entry]) -> dict[int, Path]:
    """The replay page of each scenario: ``out`` for one, ``<stem>-<scenario>.html`` for several."""
    if len(entries) == 1:
        return {0: Path(out)}
    base = Path(out)
    pages: dict[int, Path] = {}
    for i, e in enumerate(entries):
        slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", e.scenario.name).strip("_") or f"scenario{i}"
        pages[i] = base.with_name(f"{base.stem}-{slug}{base.suffix or '.html'}")
    if len(set(pages.values())) != len(pages):
        pages = {i: p.with_name(f"{p.stem}-{i}{p.suffix}") for i, p in pages.items()}
    return pages


def _replay(out: Path | None, e: _Entry, cert: Certificate) -> None:
    """Write the replay page of ``cert`` in ``e``'s scenario to ``out`` (None: no page)."""
    if out is None:
        return
    from planbench.bench.replay import replay_scenario
    from planbench.reactive.solvability import certificate_record

    record = certificate_record(e.scenario, cert)
    title = f"certificate of {e.scenario.name}: goal reached at {cert.time_to_goal:.2f} s"
    replay_scenario(out, e.scenario, record.path, record.times, title)


def _write(path: Path, data: Any) -> None:
    """Replace ``path`` by ``data`` (JSON) at once: an interrupted write leaves the old file."""
    text = json.dumps(data, indent=1) + "\n"
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp, os.stat(path).st_mode & 0o7777)
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise PlanbenchError(f"cannot write {path}: {exc.strerror or exc}") from None

"""Certify the generated ``dynamic`` set in place: every scenario it keeps is proven solvable.

``python -m planbench.reactive.certify_set [FILE] [--budget S] [--redraws N]`` is the step after
``python -m planbench.reactive.generator`` (default FILE: ``planbench/data/scenarios/dynamic.json``).
For each geometry of the set (a base problem, behaviour and speed: both sensing models share it) it
verifies the certificate the file holds or searches one with the omniscient space-time planner
(:mod:`planbench.reactive.spacetime`, within ``--budget`` seconds), and stores it in the file
under each scenario's ``certificate`` key. A (problem, behaviour) one of whose geometries gets no
certificate is drawn again (its draw added to the file's ``refused_draws``, so that the generator
draws the same again), up to ``--redraws`` times; after that its scenarios are dropped and listed
under ``dropped`` with the reason. The file is rewritten after every (problem, behaviour), so an
interrupted run keeps what it certified; ``"certified": true`` when every scenario kept has one.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from planbench.errors import PlanbenchError
from planbench.reactive import generator
from planbench.reactive.certificate import Certificate
from planbench.reactive.scenario import Scenario
from planbench.reactive.solvability import verify_certificate
from planbench.reactive.spacetime import SpaceTimeSettings, find_certificate

__all__ = ["certify_set"]

DEFAULT_FILE = Path("planbench/data/scenarios/dynamic.json")


def certify_set(
    path: Path = DEFAULT_FILE, budget: float = 60.0, redraws: int = 2, log: Callable[[str], None] = print
) -> dict[str, int]:
    """Certify the set file ``path`` in place (module docstring); the counts of what happened."""
    data = json.loads(path.read_text())
    refs = list(data["base_problems"])
    counts = {"verified": 0, "found": 0, "redrawn": 0, "dropped": 0}
    dropped = data.setdefault("dropped", {})
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for d in data["scenarios"]:
        groups.setdefault((d["metadata"]["base"], d["metadata"]["behaviour"]), []).append(d)
    for (ref, behaviour), items in groups.items():
        for attempt in range(redraws + 1):
            failed = None
            by_geometry: dict[str, Any] = {}
            for d in items:
                key = _geometry_key(d)
                scenario = _scenario(d)
                cert = by_geometry.get(key)
                if cert is None and d.get("certificate") is not None:
                    cert = Certificate.from_dict(d["certificate"])
                if cert is not None and verify_certificate(scenario, cert).success:
                    counts["verified"] += 1
                else:
                    t0 = time.perf_counter()
                    search = find_certificate(scenario, SpaceTimeSettings(budget=budget))
                    if search.certificate is None:
                        failed = f"{d['name']}: no certificate in {budget:g} s ({search.reason})"
                        break
                    cert = dataclasses.replace(search.certificate, budget=budget)
                    counts["found"] += 1
                    log(f"{d['name']}: certificate found in {time.perf_counter() - t0:.1f} s")
                by_geometry[key] = cert
                d["certificate"] = cert.to_dict()
            if failed is None:
                break
            log(failed)
            if attempt == redraws:
                for d in items:
                    dropped[d["name"]] = failed
                data["scenarios"] = [d for d in data["scenarios"] if d["name"] not in dropped]
                counts["dropped"] += len(items)
                break
            data["refused_draws"].append({"base": ref, "behaviour": behaviour, "draw": items[0]["metadata"]["draw"]})
            items[:] = _redraw(data, ref, behaviour, refs.index(ref) + 1)
            counts["redrawn"] += len(items)
        data["certified"] = all(d.get("certificate") is not None for d in data["scenarios"])
        _write(path, data)
    return counts


def _scenario(d: dict[str, Any]) -> Scenario:
    """The scenario of a set entry, read without its certificate (judged apart: a geometry's
    certificate serves its sensing variants)."""
    return Scenario.from_dict({k: v for k, v in d.items() if k != "certificate"}, f"dynamic set: {d['name']}")


def _geometry_key(d: dict[str, Any]) -> str:
    """What a certificate depends on: all but the sensing, name, metadata and certificate."""
    return json.dumps({k: v for k, v in d.items() if k not in ("sensing", "name", "metadata", "certificate")})


def _redraw(data: dict[str, Any], ref: str, behaviour: str, index: int) -> list[dict[str, Any]]:
    """The six scenarios of (``ref``, ``behaviour``) drawn again without the refused draws, put in
    the place of the old ones in ``data``."""
    refused = [int(r["draw"]) for r in data["refused_draws"] if (r["base"], r["behaviour"]) == (ref, behaviour)]
    problem = generator.base_problem(ref)
    new = {
        s.name: s.to_dict()
        for speed in generator.SPEEDS
        for sensing in generator.SENSING
        for s in [generator.scenario(problem, ref, behaviour, speed, sensing, data["seed"], index, refused)]
    }
    data["scenarios"] = [new.get(d["name"], d) for d in data["scenarios"]]
    return [d for d in data["scenarios"] if d["name"] in new]


def _write(path: Path, data: Any) -> None:
    """Replace ``path`` by ``data`` at once: an interrupted write leaves the old file."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w") as f:
        f.write(json.dumps(data, indent=1) + "\n")
    os.chmod(tmp, os.stat(path).st_mode & 0o7777)  # mkstemp's file is private: keep the set's mode
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m planbench.reactive.certify_set", description=__doc__.split("\n")[0])
    ap.add_argument("file", nargs="?", type=Path, default=DEFAULT_FILE, help="the set file (default: %(default)s)")
    ap.add_argument("--budget", type=float, default=60.0, help="[s] of search per scenario geometry")
    ap.add_argument("--redraws", type=int, default=2, help="new draws of a (problem, behaviour) before dropping it")
    args = ap.parse_args(argv)
    try:
        counts = certify_set(args.file, args.budget, args.redraws)
    except PlanbenchError as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    print(", ".join(f"{k} {v}" for k, v in counts.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``planbench robot add``: write a robot settings file (TOML) for a URDF (:mod:`~planbench.problems.robot_setup`).

This module is imported to build the parser on every ``planbench`` command: it imports pinocchio
and the planners only inside the command.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from planbench.errors import PlanbenchError, PlannerUnavailableError


def _fix(text: str) -> tuple[str, float | None]:
    """``NAME`` or ``NAME=VALUE`` of ``--fix``."""
    name, eq, value = text.partition("=")
    if not name:
        raise argparse.ArgumentTypeError(f"expected NAME or NAME=VALUE, got {text!r}")
    if not eq:
        return name, None
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: {value!r} is not a number") from None


def cmd_robot_add(args: argparse.Namespace) -> int:
    from planbench.files.inputs import check_writable
    from planbench.files.outputs import check_output
    from planbench.problems.robot_setup import describe, plan_check, propose, settings_text

    if not 1 <= args.samples <= 10**7:
        raise PlanbenchError(f"--samples must be between 1 and 10000000, got {args.samples}")
    if not 0 <= args.seed < 2**63:
        raise PlanbenchError(f"--seed must be an integer with 0 <= seed < 2**63, got {args.seed}")
    out = Path(args.out)
    if out.suffix != ".toml":
        raise PlanbenchError(
            f"--out {out}: a robot settings file must end in .toml (load_robot reads it by its suffix)"
        )
    if out.exists() and not args.force:
        raise PlanbenchError(f"--out {out} exists; --force to overwrite it")
    check_output(str(out))
    check_writable(str(out), "--out")
    proposal = propose(
        args.urdf,
        args.srdf,
        name=args.name or out.stem,
        ee_frame=args.ee_frame,
        fixed=dict(args.fix or []),
        samples=args.samples,
        seed=args.seed,
    )
    text = settings_text(proposal, out)
    try:
        out.write_text(text)
    except OSError as exc:
        raise PlanbenchError(f"cannot write {out}: {exc.strerror}") from exc
    print(f"{out}: robot {proposal.settings.name!r}")
    for line in describe(proposal):
        print(f"  {line}")
    if args.no_check:
        return 0
    try:
        check = plan_check(out, seed=args.seed)
    except PlannerUnavailableError as exc:
        print(f"plan check not run: {exc}")
        return 0
    if check.success:
        print(
            f"plan check: {check.planner} planned home to a configuration {check.distance:.2f} rad away in "
            f"{check.planning_time * 1000:.0f} ms (empty scene; the path checked by planbench)"
        )
        return 0
    print(f"plan check FAILED: {check.planner}: {check.message}")
    return 1


def add_commands(sub: Any) -> None:
    p = sub.add_parser(
        "robot",
        help="robot settings files: `robot add URDF --out robot.toml`",
        description='Robot settings files (TOML, for planbench.load_robot(path) and a problem\'s "robot").',
    )
    robot_sub = p.add_subparsers(dest="robot_command", required=True, parser_class=type(p))
    a = robot_sub.add_parser(
        "add",
        help="write a robot's settings file from its URDF (and SRDF), as MoveIt's setup assistant would",
        description="Write a robot's settings file (TOML) from its URDF: the planned joints (the chain to the tool "
        "frame; continuous joints over [-pi, pi]), the tool frame, a collision-free home, and the link pairs never "
        "checked for self-collision (adjacent, colliding at the default configuration, always or never colliding "
        "over random configurations, as MoveIt's setup assistant finds them); then plan once with it "
        "(ompl-rrtconnect, empty scene). Exit code 0: written and planned; 1: written, the plan check failed; "
        "2: bad input. See docs/robots-and-problems.md#adding-a-robot.",
    )
    a.add_argument("urdf", help="the robot's URDF file")
    a.add_argument("--srdf", help="its SRDF: disabled pairs, end effector, group states are used")
    a.add_argument("--out", required=True, help="the settings file to write (.toml)")
    a.add_argument("--name", help="the robot's name (default: the --out file's stem)")
    a.add_argument("--ee-frame", help="the tool frame, a link of the URDF (default: proposed, see the docs)")
    a.add_argument(
        "--fix",
        action="append",
        type=_fix,
        metavar="JOINT[=VALUE]",
        help="hold a joint fixed (repeatable), at VALUE [rad or m] or at 0 (mid-range when 0 is outside it)",
    )
    a.add_argument("--samples", type=int, default=10000, help="random configurations for the collision pairs")
    a.add_argument("--seed", type=int, default=0, help="of the random configurations and of the plan check")
    a.add_argument("--force", action="store_true", help="overwrite --out when it exists")
    a.add_argument("--no-check", action="store_true", help="skip the plan check")
    a.set_defaults(func=cmd_robot_add)

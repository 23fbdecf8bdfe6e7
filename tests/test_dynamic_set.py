"""The shipped ``dynamic`` set: its split by base problem, and the promises of each behaviour
(planbench/reactive/generator.py's docstring) checked on the shipped scenarios themselves."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from planbench.errors import UnknownNameError
from planbench.geometry.occupancy_map import MapSettings
from planbench.problem import Problem
from planbench.reactive import Scenario, certify_set, generator
from planbench.reactive.behaviours import BEHAVIOURS, draw
from planbench.reactive.certificate import Certificate
from planbench.reactive.checker import TickChecker
from planbench.reactive.generator import BASE_PROBLEMS, SPEEDS, TUNE_PROBLEMS, _rng, base_problem, hides, path_frame
from planbench.reactive.scenario import MovingObstacle
from planbench.reactive.sets import load_scenarios
from planbench.scene import Scene

PROBLEMS = ("0001", "0007")  # a Panda problem and an xArm7 one: every behaviour checked on both


def _shipped() -> dict:
    return json.loads((resources.files("planbench") / "data" / "scenarios" / "dynamic.json").read_text())


@pytest.fixture(scope="module")
def by_behaviour() -> dict[str, list[Scenario]]:
    found: dict[str, list[Scenario]] = {}
    for index in PROBLEMS:
        for s in load_scenarios(f"dynamic:*/{index}"):
            found.setdefault(s.metadata["behaviour"], []).append(s)
    return found


def _alone(s: Scenario) -> TickChecker:
    """The checker of the scenario's moving obstacles alone (its static scene left out)."""
    p = s.problem
    return TickChecker(Scenario(Problem.create(p.robot, Scene(), p.start, p.goal.q), s.moving))


def test_the_split_is_by_base_problem_and_covers_the_set():
    tune, test, everything = (load_scenarios(f"dynamic{s}") for s in ("-tune", "-test", ""))
    assert tune and test and len(tune) + len(test) == len(everything) == 432
    assert {s.name for s in tune} | {s.name for s in test} == {s.name for s in everything}
    bases = {split: {s.metadata["base"] for s in found} for split, found in (("tune", tune), ("test", test))}
    assert not bases["tune"] & bases["test"]  # no test scene was seen while tuning
    assert bases["tune"] == set(TUNE_PROBLEMS) and bases["tune"] | bases["test"] == set(BASE_PROBLEMS)
    assert all(s.metadata["split"] == "tune" for s in tune) and all(s.metadata["split"] == "test" for s in test)
    robots = {"panda", "ur5", "xarm7"}
    assert {s.problem.robot.name for s in tune} == robots == {s.problem.robot.name for s in test}
    assert _shipped()["splits"] == {
        "tune": sorted(bases["tune"], key=BASE_PROBLEMS.index),
        "test": [ref for ref in BASE_PROBLEMS if ref in bases["test"]],
    }
    assert len(load_scenarios("dynamic-smoke")) == 4


def test_a_family_selector_can_name_one_half_of_the_split():
    depth = load_scenarios("dynamic-test:*_depth")
    assert len(depth) == 144 and {s.metadata["split"] for s in depth} == {"test"}
    assert all(s.sensing.model == "depth" for s in depth)
    assert {s.name for s in load_scenarios("dynamic-tune:panda_*/0001")} == {
        s.name for s in load_scenarios("dynamic:panda_*/0001")
    }  # problem 0001 is the Panda's tuning problem
    with pytest.raises(UnknownNameError):
        load_scenarios("dynamic-test:panda_*/0001")  # ... so the test half has none of it


def test_the_set_has_every_behaviour_speed_and_sensing_on_every_problem():
    everything = load_scenarios("dynamic")
    combos = {(s.metadata["base"], s.metadata["behaviour"], s.metadata["speed"], s.sensing.model) for s in everything}
    assert len(combos) == len(everything) == len(BASE_PROBLEMS) * len(BEHAVIOURS) * len(SPEEDS) * 2
    assert all(isinstance(s.to_dict()["problem"], str) for s in everything)  # by reference: a small file


@pytest.mark.parametrize("behaviour", BEHAVIOURS)
def test_the_generator_gives_the_shipped_draws(behaviour, by_behaviour):
    """The shipped obstacles are the generator's draw for the recorded draw index (the search for
    that index is the slow part: tests/test_dynamic_bench.py repeats it for the first three)."""
    for s in by_behaviour[behaviour][::2]:  # truth sensing; depth has the same obstacles
        rng = _rng(0, s.metadata["base"], behaviour, s.metadata["draw"])
        made = draw(behaviour, SPEEDS[s.metadata["speed"]], path_frame(s.problem), rng)
        assert [m.to_dict() for m in made] == [m.to_dict() for m in s.moving]


def test_depth_scenarios_are_seen_by_the_generators_cameras_and_map(by_behaviour):
    """Every shipped depth scenario has the generator's rig: the front camera first, the one over
    the shoulder behind the base second, both aimed at the path's midpoint; ``occluded`` the front
    camera alone (the shoulder camera would see its box). The map has the default sensor model.
    Truth scenarios have no camera. The sensing is what the generator writes, value for value."""
    for behaviour, scenarios in by_behaviour.items():
        for s in scenarios:
            frame = path_frame(s.problem)
            assert s.sensing.to_dict() == generator._sensing(s.sensing.model, frame.m, behaviour).to_dict()
            if s.sensing.model == "truth":
                assert s.sensing.to_dict().get("cameras") is None
                continue
            front, *others = s.sensing.cameras
            assert np.allclose(front.position, frame.camera, atol=2e-4) and np.allclose(
                front.look_at, frame.m, atol=2e-4
            )
            assert s.sensing.map == MapSettings() and s.metadata["generator"] == generator.GENERATOR_VERSION
            if behaviour == "occluded":
                assert others == []
                continue
            (shoulder,) = others
            behind = -np.asarray(shoulder.position[:2]) @ np.asarray(frame.m[:2]) / np.linalg.norm(frame.m[:2])
            assert behind == pytest.approx(0.5, abs=2e-4)
            assert shoulder.position[2] == pytest.approx(frame.m[2] + 1.0, abs=2e-4)
            assert np.allclose(shoulder.look_at, frame.m, atol=2e-4)


def test_common_promises(by_behaviour):
    for behaviour, found in by_behaviour.items():
        for s in found[::2]:
            checker, start = _alone(s), np.asarray(s.problem.start)
            assert min(checker.clearance(start, t) for t in np.arange(0, 0.5, 0.05)) >= 0.05, s.name
            late = np.arange(0.5 * s.horizon, s.horizon, 0.25)
            assert min(checker.clearance(np.asarray(s.problem.goal.q), t) for t in late) >= 0.02, s.name
            if behaviour != "occluded":  # its box stands still
                assert max(m.speed_bound() for m in s.moving) == pytest.approx(SPEEDS[s.metadata["speed"]], rel=0.15)


def test_blocking_parks_on_the_goal_then_leaves(by_behaviour):
    for s in by_behaviour["blocking"]:
        (m,) = s.moving
        arrive, leave = m.motion.times[1:3]
        assert 2.0 <= leave - arrive <= 5.0
        goal = np.asarray(s.problem.goal.pose.position)
        for t in np.linspace(arrive, leave, 5):
            assert np.linalg.norm(np.asarray(m.at(t).position) - goal) <= 0.031
        assert _alone(s).clearance(np.asarray(s.problem.goal.q), 0.5 * (arrive + leave)) < 0  # the goal blocked
        assert m.disappear is not None and not m.present(m.disappear) and m.disappear <= 0.5 * s.horizon


def test_appearing_is_absent_before_it_appears(by_behaviour):
    for s in by_behaviour["appearing"]:
        (m,) = s.moving
        assert 0.5 <= m.appear <= 2.0 and m.disappear is None
        assert not m.present(0.0) and not m.present(m.appear - 0.01) and m.present(m.appear)
        assert m.name not in {o.name for o in s.scene_at(m.appear - 0.01).obstacles}
        assert m.name in {o.name for o in s.scene_at(m.appear).obstacles}
        assert _alone(s).clearance(np.asarray(s.problem.start), m.appear) >= 0.05  # not on the arm at its start


def test_pair_has_two_moving_obstacles(by_behaviour):
    for s in by_behaviour["pair"]:
        assert len(s.moving) == 2 and len({m.name for m in s.moving}) == 2
        assert all(m.speed_bound() > 0 for m in s.moving)
        assert all(m.name.startswith(("crossing", "sliding")) for m in s.moving)


def _to_path(m: MovingObstacle, t: float, ps: np.ndarray, pg: np.ndarray) -> float:
    """Distance [m] from a capsule's segment at time ``t`` to the segment ``ps``-``pg``."""
    o = m.at(t)
    axis = o.rotation[:, 2] * 0.5 * float(o.length)  # type: ignore[arg-type]
    ends = np.asarray(o.position) + np.outer(np.linspace(-1, 1, 21), axis)
    seg = np.linspace(0, 1, 101)[:, None] * (pg - ps) + ps
    return float(np.min(np.linalg.norm(ends[:, None] - seg[None], axis=2)))


def test_reaching_comes_to_the_path_and_withdraws(by_behaviour):
    for s in by_behaviour["reaching"]:
        (m,) = s.moving
        assert m.obstacle.type == "capsule" and m.motion.type == "waypoints"
        f = path_frame(s.problem)
        held = 0.5 * (m.motion.times[1] + m.motion.times[2])
        near = _to_path(m, held, f.ps, f.pg)
        assert near <= 0.08 + float(m.obstacle.radius) + 0.01  # fingertips 0-8 cm short of it
        assert _to_path(m, 0.0, f.ps, f.pg) > near + 0.3  # 35-50 cm away before the reach
        assert m.disappear == m.motion.times[-1] and not m.present(m.disappear)


def test_occluded_box_is_hidden_from_the_camera_by_the_moving_board(by_behaviour):
    for s in by_behaviour["occluded"]:
        box, board = s.moving
        assert box.speed_bound() == 0 and board.speed_bound() > 0
        camera = np.asarray(path_frame(s.problem).camera)
        if s.sensing.model == "depth":
            assert np.allclose(s.sensing.cameras[0].position, camera)
        target = np.asarray(box.obstacle.position)
        seen = [hides(board.at(t), camera, target) for t in np.arange(0.0, s.horizon, 0.1)]
        assert seen[0] and not all(seen)  # hidden at the start, seen at other times


def test_every_shipped_scenario_is_certified():
    """The set file's certificates are there (``planbench check-scenario`` verifies them: slow)."""
    data = _shipped()
    assert data["certified"] is True and not data["dropped"]
    assert all(d.get("certificate") for d in data["scenarios"]) and len(data["scenarios"]) == 432
    # a refused draw is drawn again by the generator: its scenarios name the next valid draw
    for r in data["refused_draws"]:
        found = [
            d
            for d in data["scenarios"]
            if (d["metadata"]["base"], d["metadata"]["behaviour"]) == (r["base"], r["behaviour"])
        ]
        assert len(found) == 6 and all(d["metadata"]["draw"] != r["draw"] for d in found)


def _small_set(tmp_path, base: str, behaviour: str) -> tuple[Path, int]:
    """A set file holding the six shipped scenarios of one (problem, behaviour), uncertified."""
    data = _shipped()
    items = [d for d in data["scenarios"] if (d["metadata"]["base"], d["metadata"]["behaviour"]) == (base, behaviour)]
    for d in items:
        d.pop("certificate", None)
    data.update(scenarios=items, refused_draws=[], certified=False)
    path = tmp_path / "set.json"
    path.write_text(json.dumps(data))
    return path, items[0]["metadata"]["draw"]


def _fake_search(refused_draw: int | None):
    """A space-time search that finds no certificate for ``refused_draw`` (None: for no draw)."""

    def find(scenario, settings=None):
        if refused_draw is None or scenario.metadata["draw"] == refused_draw:
            return SimpleNamespace(certificate=None, reason="no path (test)")
        q = np.asarray(scenario.problem.start)
        return SimpleNamespace(certificate=Certificate(np.array([0.0, 1.0]), np.stack([q, q]), 1.0), reason="")

    return find


def test_certification_redraws_a_refused_draw_and_stores_certificates(tmp_path, monkeypatch):
    path, k = _small_set(tmp_path, "mbm:box/0001", "crossing")
    monkeypatch.setattr(certify_set, "find_certificate", _fake_search(k))
    monkeypatch.setattr(certify_set, "verify_certificate", lambda s, c: SimpleNamespace(success=True))
    path.chmod(0o644)
    counts = certify_set.certify_set(path, budget=1.0, redraws=1, log=lambda _: None)
    assert path.stat().st_mode & 0o777 == 0o644
    data = json.loads(path.read_text())
    assert counts["redrawn"] == 6 and counts["dropped"] == 0 and data["certified"] is True
    assert data["refused_draws"] == [{"base": "mbm:box/0001", "behaviour": "crossing", "draw": k}]
    assert len(data["scenarios"]) == 6 and all(d["metadata"]["draw"] > k for d in data["scenarios"])
    assert all(d["certificate"]["budget"] == 1.0 for d in data["scenarios"])
    # the generator honours the refused draw: regenerating gives what the certification drew
    redrawn = generator.scenario(base_problem("mbm:box/0001"), "mbm:box/0001", "crossing", "fast", "depth", refused=[k])
    assert redrawn.metadata["draw"] == data["scenarios"][0]["metadata"]["draw"]


def test_certification_drops_what_gets_no_certificate(tmp_path, monkeypatch):
    path, _ = _small_set(tmp_path, "mbm:box/0001", "sliding")
    monkeypatch.setattr(certify_set, "find_certificate", _fake_search(None))
    counts = certify_set.certify_set(path, budget=1.0, redraws=0, log=lambda _: None)
    data = json.loads(path.read_text())
    assert counts["dropped"] == 6 and not data["scenarios"] and len(data["dropped"]) == 6
    assert all("no path (test)" in why for why in data["dropped"].values())

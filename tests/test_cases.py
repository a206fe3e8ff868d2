"""The minimal cases found from outside (tests/cases/, copied from ../shared/cases/): each
expects what tests/cases/README.md says it should show.

A case main did not meet would be marked xfail with ``strict`` (failing the suite as soon as a
change makes it pass); none is now.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from fleet.engine import World
from fleet.errors import FleetError, ScenarioError
from fleet.floor import load_floor
from fleet.paths import PathPlanner
from fleet.scenario import load_scenario

CASES = Path(__file__).resolve().parent / "cases"


def summary_of(case: str, file: str = "scen.toml", **override: Any) -> dict[str, Any]:
    scenario = load_scenario(CASES / case / file)
    if override:
        scenario = scenario.override(**override)
    return World(scenario).run().summary


@pytest.mark.parametrize("controller", ["follower", "mpc"])
def test_an_idle_robot_parked_on_a_path_never_blocks_it_for_good(controller: str) -> None:
    s = summary_of("parked_on_path", controller=controller)
    assert s["jobs"]["completed"] == s["jobs"]["released"] == 2
    assert s["violations"]["collision"] == 0


@pytest.mark.parametrize("controller", ["follower", "mpc"])
def test_a_trip_via_a_station_where_a_robot_is_parked_is_delivered(controller: str) -> None:
    scenario = load_scenario(CASES / "via_parked_robot" / "scen.toml").override(
        controller=controller
    )
    world = World(scenario)
    s = world.run().summary
    assert s["jobs"]["completed"] == s["jobs"]["released"] == 1
    assert s["violations"]["collision"] == 0
    # The block is reported, and resolved by the idle robot stepping aside, then going home:
    # r02 sends the idle r01 aside once it made no progress for `IDLE_ASK_S` (the make_way
    # event names both), before the deadlock watch (30 s) would report it.
    asides = [(e.robot, e.station) for e in world.recorder.events if e.event == "make_way"]
    assert ("r01", "r02") in asides
    assert s["engine"]["made_way"] >= 1
    r01 = world.robots["r01"]
    assert math.dist((r01.x, r01.y), r01.home) <= scenario.arrival_tolerance_m


def test_jobs_to_one_station_are_all_delivered() -> None:
    # Robots crowding the one station hand jobs back (the follower's congestion there, issue
    # 16's liveness, costs time: the last delivery is at 277 s), so the run is the README's 900 s.
    s = summary_of("same_station", duration=900)
    assert s["jobs"]["completed"] == s["jobs"]["released"] == 3
    assert s["jobs"]["failed"] == 0


@pytest.mark.parametrize(("dt", "a_max"), [(0.5, 0.5), (1.0, 0.5), (0.25, 1.0), (0.25, 2.0)])
def test_the_reference_is_valid_on_a_floor_the_loader_accepts(dt: float, a_max: float) -> None:
    floor = load_floor(CASES / "reference_selfcheck" / "floor.toml")
    start, goal = floor.station("st3"), floor.station("st0")
    ref = PathPlanner(floor, 1.0, a_max).reference((start.x, start.y), (goal.x, goal.y), dt)
    assert ref.steps > 0


def test_the_robot_on_the_case_floor_delivers_its_job() -> None:
    # It used to fail every command (its reference failed the self-check) and never move.
    s = summary_of("reference_selfcheck")
    assert s["jobs"]["completed"] == 1


@pytest.mark.parametrize(
    ("file", "seed"),
    [
        (f, seed)
        for f, seeds in (("p1", (2, 4, 5)), ("p05", (4, 5)), ("p025", (4, 5)))
        for seed in seeds
    ],
)
def test_the_follower_never_collides_at_a_period_scenarios_accept(file: str, seed: int) -> None:
    try:
        s = summary_of("follower_coarse_period", f"{file}.toml", seed=seed)
    except ScenarioError as exc:  # refusing a period (or sensing) it cannot keep safe is allowed
        assert exc.field.endswith(("period_s", "sensing_radius_m")), exc
        return
    assert s["violations"]["collision"] == 0
    assert s["jobs"]["completed"] >= 1


def test_a_robot_that_can_never_move_fails_the_run_naming_it(monkeypatch, tmp_path, capsys):
    # The case as it was: the controller fails every command while the robot has a goal.
    import fleet.engine.agents as agents_module
    from fleet.cli import main
    from fleet_plugins.follower import PathFollower

    class Failing(PathFollower):
        def compute(self, obs):
            if obs.goal is not None:
                raise FleetError("the reference failed its safety self-check")
            return super().compute(obs)

    monkeypatch.setattr(agents_module, "load_controller", lambda name, options: Failing())
    s = summary_of("reference_selfcheck")
    assert s["jobs"]["completed"] == 0
    (robot,) = s["per_robot"]
    assert robot["goal_commands"] == robot["goal_errors"] > 0
    assert s["stuck_robots"] == [
        {
            "robot": "r01",
            "reason": f"every one of its {robot['goal_errors']} commands while it had somewhere "
            "to go was an error (its controller failed, or no command came)",
        }
    ]
    scen = CASES / "reference_selfcheck" / "scen.toml"
    assert main(["run", str(scen), "--out", str(tmp_path / "run"), "--no-figures"]) == 1
    assert "robot r01 could never move" in capsys.readouterr().err


def test_a_robot_that_moves_is_not_reported_stuck() -> None:
    s = summary_of("reference_selfcheck")
    (robot,) = s["per_robot"]
    assert s["stuck_robots"] == [] and robot["goal_errors"] == 0 < robot["goal_commands"]

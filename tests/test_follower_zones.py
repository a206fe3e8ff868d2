"""A follower's brake keeps to the zones' speed limits (issue 16, safety).

The follower checks, before each tracking command, that braking after it would stay in the free
space (`Guard.stops_inside`) and, now, within the speed limit of every region it enters
(`Guard.stops_within_limits`): when a neighbour makes it hold, it brakes straight along its line
of travel, and on a path that skirts a slow zone at a bend that line runs into the zone.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from shapely.geometry import box

from fleet.floor import FloorSpec, SpeedZone, Station, compile_floor
from fleet.plugins import Observation, RobotSpec
from fleet_plugins.follower.guard import Guard
from fleet_plugins.follower.yielding import braking_path
from tests.scripts import load_script

fz = load_script("fuzz_floors")

CASES = Path(__file__).resolve().parent / "safety_cases"
SPEC = RobotSpec(v_max=1.0, a_max=0.5, radius=0.3, period=0.25)


def slow_zone_guard() -> Guard:
    """A guard on a 20 x 10 m hall whose right part (x >= 10) is a 0.3 m/s zone."""
    spec = FloorSpec(
        source="<zone hall>",
        name="zone hall",
        boundary=box(0, 0, 20, 10),
        default_v_max=(1.0, 1.0),
        clearance=0.3,
        obstacles=(),
        zones=(SpeedZone("slow", box(10, 0, 20, 10), (0.3, 0.3)),),
        stations=(Station("a", 2.0, 5.0, kind="depot"), Station("b", 18.0, 5.0)),
    )
    return Guard(SPEC, compile_floor(spec), 0.1, 1.0, 4)


def braking_from(x: float, vx: float) -> tuple[Observation, list[tuple[float, float, float]]]:
    """An observation at (x, 5) going `vx` along x, and its braking path (no command)."""
    obs = Observation("r1", 0, 0.0, x, 5.0, vx, 0.0)
    dt = SPEC.period
    return obs, braking_path(dt, x + dt * vx, 5.0, vx, 0.0, dt, SPEC.a_max)


def test_a_brake_into_a_slow_zone_too_fast_is_refused():
    guard = slow_zone_guard()
    # 1 m/s braking at 0.5 m/s^2 runs 1.1 m: from x = 9.5 it crosses into the zone at about
    # 0.8 m/s; from 8.5 it is at rest before the boundary.
    assert not guard.stops_within_limits(*braking_from(9.5, 1.0))
    assert guard.stops_within_limits(*braking_from(8.5, 1.0))
    # Slower than the zone's limit all the way: allowed, in the zone or not.
    assert guard.stops_within_limits(*braking_from(9.9, 0.3))
    assert guard.stops_within_limits(*braking_from(12.0, 0.25))
    # Away from the zone, or at rest.
    assert guard.stops_within_limits(*braking_from(9.5, -1.0))
    assert guard.stops_within_limits(Observation("r1", 0, 0.0, 9.9, 5.0, 0.0, 0.0), [])


def test_a_robot_held_at_a_bend_beside_a_slow_zone_does_not_brake_into_it(tmp_path):
    # Fuzz case s31-0360 (run cut to 115 s): r01 drove home at 0.89 m/s on a path that
    # touched zone z1 (0.33 m/s) at a bend and ran on beside it; held by r04 ahead one step
    # before the bend, it braked straight on, into z1 at 0.61 m/s (the oracle and the engine's
    # checker both counted it). Judged by the fuzz's oracle, from the map file alone.
    folder = tmp_path / "case"
    shutil.copytree(CASES / "brake_past_a_bend", folder)
    outcome = fz.run_folder(folder)
    assert outcome.status != "refused", outcome.refusal
    assert [f.kind for f in outcome.findings] == []
    assert outcome.engine["speed_zone"] == 0

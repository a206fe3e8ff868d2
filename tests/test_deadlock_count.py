"""The deadlock watch (fleet.engine.sensing) counts a stuck robot once until it makes progress
again, however often robots come and go round it (issue 16: at 80 MPC robots one robot waiting
beside a station was reported 9 times in 20 s, 63 reports of 25 waits)."""

from __future__ import annotations

from pathlib import Path

from fleet.engine import World
from fleet.scenario import load_scenario

CASE = Path(__file__).resolve().parent / "cases" / "via_parked_robot"


def test_a_stuck_robot_is_counted_once_until_it_makes_progress() -> None:
    world = World(load_scenario(CASE / "scen.toml"))
    try:
        r01, r02 = world.robots["r01"], world.robots["r02"]
        after = world.scenario.deadlock_after_s
        # r01, idle, heads home (5, 10) from 10 m east of it; r02 stands beside it, or 8 m off.
        r01.x, r01.y = 15.0, 10.0
        beside, away = (15.0, 11.0), (15.0, 18.0)

        def watch(t: float, r02_at: tuple[float, float]) -> int:
            r02.x, r02.y = r02_at
            world.sensing.observe([r01], t)
            return world.recorder.stats.get("deadlocks", 0)

        assert watch(0.0, beside) == 0
        assert watch(after, beside) == 1 and r01.stalled
        assert watch(after + 1, away) == 1 and not r01.stalled  # nobody close: not stalled
        # Back beside it, no progress since: the same deadlock, not another one.
        assert watch(after + 2, beside) == 1 and r01.stalled
        events = [e for e in world.recorder.events if e.event == "deadlock"]
        assert [(e.t, e.robot, e.station) for e in events] == [(after, "r01", "r02")]
        # Once it has made progress, stuck again a deadlock period later is a new one.
        r01.x = 14.0
        assert watch(after + 3, away) == 1 and not r01.stalled
        assert watch(2 * after + 3, (14.0, 11.0)) == 2 and r01.stalled
    finally:
        world._close_bus()

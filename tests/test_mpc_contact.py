"""MPC robots that met on random floors (issue 16), rebuilt as real runs and checked for contact.

Each floor is a falsifying example of `tests/test_fleet_properties.py`'s
``test_mpc_robots_never_collide_on_random_floors``, scenario built the same way (two MPC robots,
radius 0.3, period 0.5 s, horizon 10, sensing 5 m, a job each way via the other station). The
contact is judged twice: by the engine's safety checker (at the samples) and here, between the
samples too (both robots move in straight lines over a step, so the closest approach of their
recorded trajectories is exact).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from shapely import wkt
from shapely.geometry import box

from fleet.engine import World
from fleet.floor import Floor, FloorSpec, Obstacle, SpeedZone, Station, compile_floor
from fleet.paths import PathPlanner
from fleet.plugins import Neighbour, Observation, RobotSpec
from fleet.scenario import JobsConfig, PluginChoice, RobotsConfig, Scenario, ScriptedJob
from fleet_plugins.mpc.neighbours import clear_of_neighbours, closest_approach

RADIUS = 0.3


def run_property_scenario(floor: Floor, gap: float) -> tuple[dict, float]:
    """The property test's scenario on `floor` (second job `gap` s after the first): the run's
    summary and the robots' closest approach over the whole run, between samples too."""
    a, b = floor.station("a"), floor.station("b")
    trip = PathPlanner(floor, 1.0, 0.5).path((a.x, a.y), (b.x, b.y))
    scenario = Scenario(
        name="mpc-contact",
        source="<tests/test_mpc_contact.py>",
        map=Path("<random floor>"),
        duration_s=30.0 + 3.0 * trip.travel_time,
        robots=(RobotsConfig(count=2, start=("a", "b"), radius=RADIUS, period_s=0.5),),
        controller=PluginChoice("mpc", {"horizon": 10}),
        dispatcher=PluginChoice("auction"),
        jobs=JobsConfig(
            mode="scripted",
            scripted=(ScriptedJob(0.0, "b", via=("a",)), ScriptedJob(gap, "a", via=("b",))),
        ),
        sensing_radius_m=5.0,
        deadlock_after_s=10.0,
    )
    world = World(scenario, floor)
    summary = world.run().summary
    (t1, p1, _), (t2, p2, _) = (world.recorder.trajectories[r].arrays() for r in ("r01", "r02"))
    n = min(len(t1), len(t2))
    np.testing.assert_array_equal(t1[:n], t2[:n])  # one period: common sample times
    return summary, closest_approach(p1[:n], p2[:n])


def corridor_floor() -> Floor:
    """Example 5 of the derandomized property test on main (4fd2e5e): a gap between two
    machines; the robots meet head-on in it, on one line, at about 1.25 m/s each."""
    w, h = 24.772932927490587, 15.053358439210527
    m0 = (
        "POLYGON ((15.923552540252302 8.92236100994781, 13.43971243381189 11.41967995004654, "
        "11.392155366698473 8.922328846603323, 13.439712632743937 7.570621520774214, "
        "15.923552540252302 8.92236100994781))"
    )
    m1 = (
        "POLYGON ((14.594707925431504 6.860496937411275, 11.977265940498407 6.159010837759751, "
        "11.534519986555665 4.926141088441463, 14.594707925431504 6.860496937411275))"
    )
    zone = box(20.772932927490587, 7.909331646710929, w, 13.099892551431587)
    return compile_floor(
        FloorSpec(
            source="<mpc contact: corridor>",
            name="random",
            boundary=box(0, 0, w, h),
            default_v_max=(1.0, 1.0),
            clearance=0.3,
            obstacles=(Obstacle("m0", wkt.loads(m0)), Obstacle("m1", wkt.loads(m1))),
            zones=(SpeedZone("zone0", zone, (0.3, 0.3)),),
            stations=(
                Station("a", 18.099928352132714, 11.986860920607059, kind="depot"),
                Station("b", 3.3889081860729022, 4.079374686513239),
            ),
        )
    )


def test_mpc_robots_meeting_head_on_in_a_gap_never_touch() -> None:
    # Before the fix: at 28.0 s the lower-priority robot's solve was infeasible and its fallback
    # followed its old plan, which ran along the same line as the other's; the samples of the
    # two plans interleaved (0.612 m apart at every sample, 0.000 between them) and the
    # sample-only check let it through; both followed old plans into each other: 0.555 m apart
    # at 30.0 s (radii 0.3 + 0.3).
    summary, closest = run_property_scenario(corridor_floor(), 0.0)
    assert summary["violations"]["collision"] == 0
    assert closest >= 2 * RADIUS
    assert summary["violations"]["obstacle"] == 0
    assert summary["violations"]["speed_zone"] == 0
    assert summary["jobs"]["accounted"]
    assert summary["jobs"]["completed"] == 2


SPEC = RobotSpec(v_max=1.0, a_max=0.5, radius=RADIUS, period=0.5)


def test_closest_approach_sees_two_robots_pass_through_each_other_between_samples() -> None:
    # Head-on on one line at 1.25 m/s each, 0.5 s steps: every sample of one falls midway
    # between two of the other (1.25 m apart), yet they meet.
    t = np.arange(6) * 0.5
    p = np.column_stack([1.25 * t, np.zeros(6)])
    q = np.column_stack([6.25 - 1.25 * t - 0.625, np.zeros(6)])
    assert np.min(np.hypot(*(p - q).T)) >= 0.6  # the samples alone: never closer than 0.625
    assert closest_approach(p, q) == pytest.approx(0.0)
    # Side by side, 0.7 m apart: as far between the samples as at them.
    assert closest_approach(p, p + [0.0, 0.7]) == pytest.approx(0.7)
    assert closest_approach(p[:1], q[:1]) == pytest.approx(5.625)


def test_a_fallback_plan_through_a_neighbour_between_samples_is_not_clear() -> None:
    dt, steps = SPEC.period, 6
    t = np.arange(steps + 1) * dt
    mine = np.column_stack([1.25 * t, np.zeros(steps + 1)])
    theirs = tuple((float(s), 6.25 - 1.25 * float(s) - 0.625, 0.0) for s in t)
    other = Neighbour("r2", theirs[0][1], 0.0, -1.25, 0.0, RADIUS, 0, theirs)
    obs = Observation("r1", 0, 0.0, 0.0, 0.0, 1.25, 0.0, goal=(9.0, 0.0), neighbours=(other,))
    assert not clear_of_neighbours(obs, SPEC, mine)
    # The same plan with the other robot 0.7 m off its line is clear.
    aside = tuple((s, x, 0.7) for s, x, _ in theirs)
    obs = Observation(
        "r1", 0, 0.0, 0.0, 0.0, 1.25, 0.0, goal=(9.0, 0.0),
        neighbours=(Neighbour("r2", aside[0][1], 0.7, -1.25, 0.0, RADIUS, 0, aside),),
    )  # fmt: skip
    assert clear_of_neighbours(obs, SPEC, mine)

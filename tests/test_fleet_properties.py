"""Fleet safety as an invariant: on random floors, robots that share the floor never collide,
never enter an obstacle and never break a zone limit, whatever the floor, starts and goals.

Each example compiles a random floor (`tests.test_properties.random_floor`), starts a small fleet
around both of its stations, sends jobs both ways so that the robots' paths cross, and runs the
real engine with the follower (or the MPC), the auction and the bus; the safety checker judges
the recorded trajectories. The examples are derandomized: the suite sees the same floors on
every run, so a failure is reproducible and CI cannot turn red by chance.
"""

from pathlib import Path

from hypothesis import HealthCheck, assume, given, note, settings
from hypothesis import strategies as st

from fleet.engine import World
from fleet.errors import NoPathError, ScenarioError
from fleet.paths import PathPlanner
from fleet.plugins import load_dispatcher
from fleet.scenario import (
    BreakdownsConfig,
    JobsConfig,
    PluginChoice,
    RobotsConfig,
    Scenario,
    ScriptedJob,
)
from tests.test_properties import random_floor


def both_ways(at: float, i: int) -> ScriptedJob:
    """A job from one station to the other: via `a` to `b` for even `i`, else via `b` to `a`."""
    via, to = ("a", "b") if i % 2 == 0 else ("b", "a")
    return ScriptedJob(at, to, via=(via,))


@settings(
    max_examples=25, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    floor=random_floor(),
    robots=st.integers(2, 4),
    dispatcher=st.sampled_from(["auction", "greedy"]),
    gaps=st.lists(st.floats(0.0, 20.0), min_size=2, max_size=4),
)
def test_followers_never_collide_on_random_floors(floor, robots, dispatcher, gaps):
    spec = floor.spec
    note(f"boundary {spec.boundary.wkt}, clearance {spec.clearance}")
    note("obstacles " + "; ".join(o.polygon.wkt for o in spec.obstacles))
    note("stations " + "; ".join(f"{s.name} ({s.x!r}, {s.y!r})" for s in spec.stations))
    a, b = floor.station("a"), floor.station("b")
    try:
        trip = PathPlanner(floor, 1.0, 0.5).path((a.x, a.y), (b.x, b.y))
    except NoPathError:
        assume(False)
    assume(trip.length >= 3.0)  # room for robots to pass each other on the way
    # Jobs both ways (each via the other station), released at random gaps, so robots meet
    # head-on and at the stations.
    at, jobs = 0.0, []
    for i, gap in enumerate(gaps):
        at += gap
        jobs.append(both_ways(at, i))
    scenario = Scenario(
        name="fleet-property",
        source="<fleet property test>",
        map=Path("<random floor>"),
        duration_s=60.0 + 3.0 * trip.travel_time,
        robots=(RobotsConfig(count=robots, start=("a", "b"), radius=0.3),),
        dispatcher=PluginChoice(dispatcher),
        jobs=JobsConfig(mode="scripted", scripted=tuple(jobs)),
        sensing_radius_m=5.0,
        deadlock_after_s=10.0,
    )
    assert load_dispatcher(dispatcher) is not None
    try:
        world = World(scenario, floor)
    except ScenarioError:
        assume(False)  # no room for the fleet's start positions around a station
    result = world.run()
    s = result.summary
    assert s["violations"]["collision"] == 0, result.safety.examples
    assert s["violations"]["obstacle"] == 0, result.safety.examples
    assert s["violations"]["speed_zone"] == 0, result.safety.examples
    assert s["jobs"]["accounted"]
    # Not vacuous: the robots drove (some floors end in a standoff, never in contact).
    assert s["distance_m"] >= 1.0


@settings(
    max_examples=6, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(floor=random_floor(), gap=st.floats(0.0, 5.0))
def test_mpc_robots_never_collide_on_random_floors(floor, gap):
    # Two MPC robots with a short horizon (5 s at a 0.5 s period), sent past each other.
    a, b = floor.station("a"), floor.station("b")
    try:
        trip = PathPlanner(floor, 1.0, 0.5).path((a.x, a.y), (b.x, b.y))
    except NoPathError:
        assume(False)
    assume(trip.length >= 3.0)  # room for robots to pass each other on the way
    scenario = Scenario(
        name="fleet-property-mpc",
        source="<fleet property test>",
        map=Path("<random floor>"),
        duration_s=30.0 + 3.0 * trip.travel_time,
        robots=(RobotsConfig(count=2, start=("a", "b"), radius=0.3, period_s=0.5),),
        controller=PluginChoice("mpc", {"horizon": 10}),
        dispatcher=PluginChoice("auction"),
        jobs=JobsConfig(mode="scripted", scripted=(both_ways(0.0, 0), both_ways(gap, 1))),
        sensing_radius_m=6.3,  # the rule (`fleet.scenario.sensing_needed`) asks 6.26 m,
        deadlock_after_s=10.0,
    )
    try:
        world = World(scenario, floor)
    except ScenarioError:
        assume(False)
    result = world.run()
    s = result.summary
    assert s["violations"]["collision"] == 0, result.safety.examples
    assert s["violations"]["obstacle"] == 0, result.safety.examples
    assert s["violations"]["speed_zone"] == 0, result.safety.examples
    assert s["jobs"]["accounted"]
    assert s["distance_m"] >= 1.0


@settings(
    max_examples=40, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    floor=random_floor(),
    robots=st.integers(2, 4),
    mtbf=st.floats(5.0, 40.0),
    mttr=st.floats(5.0, 40.0),
    seed=st.integers(0, 1000),
    gaps=st.lists(st.floats(0.0, 10.0), min_size=2, max_size=4),
)
def test_robots_never_collide_with_broken_down_ones(floor, robots, mtbf, mttr, seed, gaps):
    # Robots break down at random on their way (braking where they are and standing there until
    # repaired): the others keep clear of them, as of every robot.
    a, b = floor.station("a"), floor.station("b")
    try:
        trip = PathPlanner(floor, 1.0, 0.5).path((a.x, a.y), (b.x, b.y))
    except NoPathError:
        assume(False)
    assume(trip.length >= 3.0)
    at, jobs = 0.0, []
    for i, gap in enumerate(gaps):
        at += gap
        jobs.append(both_ways(at, i))
    scenario = Scenario(
        name="fleet-property-breakdowns",
        source="<fleet property test>",
        map=Path("<random floor>"),
        duration_s=60.0 + 3.0 * trip.travel_time,
        seed=seed,
        robots=(RobotsConfig(count=robots, start=("a", "b"), radius=0.3),),
        jobs=JobsConfig(mode="scripted", scripted=tuple(jobs)),
        sensing_radius_m=5.0,
        deadlock_after_s=10.0,
        breakdowns=BreakdownsConfig(mtbf_s=mtbf, mttr_s=mttr),
    )
    try:
        world = World(scenario, floor)
    except ScenarioError:
        assume(False)
    result = world.run()
    s = result.summary
    assert s["violations"]["collision"] == 0, result.safety.examples
    assert s["violations"]["obstacle"] == 0, result.safety.examples
    assert s["violations"]["speed_zone"] == 0, result.safety.examples
    assert s["jobs"]["accounted"]
    # Not vacuous: robots broke down, and the others drove.
    assert s["breakdowns"]["breakdowns"] >= 1
    assert s["distance_m"] >= 1.0

"""Safety as an invariant: on random floors, the baseline never enters an obstacle or breaks a
zone limit, whatever the polygons, zones, clearance, start and goal.

Each example compiles a random floor (star-shaped, often non-convex machines; rectangular and
machine-hugging speed zones), runs the real engine with the follower through the bus, and lets
the safety checker judge the recorded trajectories.
"""

import math
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, note, settings
from hypothesis import strategies as st
from shapely.geometry import Polygon, box

from fleet.engine import World
from fleet.errors import MapError, NoPathError
from fleet.floor import FloorSpec, Obstacle, SpeedZone, Station, compile_floor
from fleet.floor.mapfile import grow
from fleet.paths import PathPlanner
from fleet.printing import PrintTask
from fleet.scenario import JobsConfig, PluginChoice, RobotsConfig, Scenario, ScriptedJob


@st.composite
def star_polygon(draw, cx: float, cy: float) -> Polygon:
    """A simple, often non-convex polygon: jittered angles around a centre, random radii."""
    n = draw(st.integers(3, 8))
    jitter = draw(st.lists(st.floats(-0.4, 0.4), min_size=n, max_size=n))
    radii = draw(st.lists(st.floats(0.8, 3.5), min_size=n, max_size=n))
    angles = [2 * math.pi * (i + j) / n for i, j in enumerate(jitter)]
    return Polygon(
        [(cx + r * math.cos(a), cy + r * math.sin(a)) for a, r in zip(angles, radii, strict=True)]
    )


@st.composite
def random_floor(draw):
    w = draw(st.floats(20, 36))
    h = draw(st.floats(14, 26))
    clearance = draw(st.sampled_from([0.0, 0.3]))
    obstacles = []
    for i in range(draw(st.integers(1, 4))):
        cx = draw(st.floats(5, w - 5))
        cy = draw(st.floats(5, h - 5))
        obstacles.append(Obstacle(f"m{i}", draw(star_polygon(cx, cy))))
    zones = []
    for i, ob in enumerate(obstacles):
        if draw(st.booleans()):
            v = draw(st.sampled_from([0.2, 0.4, 0.6]))
            zones.append(
                SpeedZone(f"buffer{i}", grow(ob.polygon, 1.0).intersection(box(0, 0, w, h)), (v, v))
            )
    for i in range(draw(st.integers(0, 2))):
        x0, y0 = draw(st.floats(0, w - 3)), draw(st.floats(0, h - 3))
        x1, y1 = x0 + draw(st.floats(2, 10)), y0 + draw(st.floats(2, 8))
        vx, vy = draw(st.sampled_from([0.3, 0.5, 0.8])), draw(st.sampled_from([0.3, 0.5, 0.8]))
        zones.append(SpeedZone(f"zone{i}", box(x0, y0, min(x1, w), min(y1, h)), (vx, vy)))
    a = (draw(st.floats(1, w - 1)), draw(st.floats(1, h - 1)))
    b = (draw(st.floats(1, w - 1)), draw(st.floats(1, h - 1)))
    assume(math.dist(a, b) > 1.0)
    spec = FloorSpec(
        source="<random floor>",
        name="random",
        boundary=box(0, 0, w, h),
        default_v_max=(1.0, 1.0),
        clearance=clearance,
        obstacles=tuple(obstacles),
        zones=tuple(zones),
        stations=(Station("a", *a, kind="depot"), Station("b", *b)),
    )
    try:
        floor = compile_floor(spec)
    except MapError:
        assume(False)  # e.g. a station drawn inside a machine
    return floor


@pytest.mark.parametrize("period", [0.25, 0.5])
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(floor=random_floor(), robots=st.integers(1, 2), seed=st.integers(0, 1000))
def test_follower_never_leaves_free_space_or_breaks_a_limit(period, floor, robots, seed):
    spec = floor.spec
    # Printed with a falsifying example, so a failure can be rebuilt as a map file.
    note(f"boundary {spec.boundary.wkt}, clearance {spec.clearance}")
    note("obstacles " + "; ".join(o.polygon.wkt for o in spec.obstacles))
    note("zones " + "; ".join(f"{z.v_max} {z.polygon.wkt}" for z in spec.zones))
    note("stations " + "; ".join(f"{s.name} ({s.x!r}, {s.y!r})" for s in spec.stations))
    a, b = floor.station("a"), floor.station("b")
    try:
        trip = PathPlanner(floor, 1.0, 0.5).path((a.x, a.y), (b.x, b.y))
    except NoPathError:
        assume(False)  # start and goal in different parts of the floor
    scenario = Scenario(
        name="property",
        source="<property test>",
        map=Path("<random floor>"),
        duration_s=30.0 + 4.0 * trip.travel_time,
        seed=seed,
        robots=(RobotsConfig(count=robots, start=("a",), period_s=period, radius=0.3),),
        jobs=JobsConfig(mode="scripted", scripted=(ScriptedJob(0.0, "b"), ScriptedJob(1.0, "b"))),
    )
    world = World(scenario, floor)
    result = world.run()
    assert result.summary["violations"]["obstacle"] == 0, result.safety.examples
    assert result.summary["violations"]["speed_zone"] == 0, result.safety.examples
    # Not vacuous: the robots really drove the trip.
    assert result.summary["jobs"]["completed"] >= 1
    assert result.summary["distance_m"] >= trip.length - 1e-6


@st.composite
def print_tasks(draw):
    """A random print: 1-6 back-to-back tasks of random kinds and lengths (seconds)."""
    tasks, t = [], 0.0
    for _ in range(draw(st.integers(1, 6))):
        length = draw(st.floats(1.0, 25.0))
        kind = draw(st.sampled_from(["contour", "infill", "support", "travel"]))
        tasks.append(PrintTask(kind, t, t + length))
        t += length
    return tuple(tasks)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    floor=random_floor(),
    tasks=print_tasks(),
    caps=st.fixed_dictionaries(
        {k: st.sampled_from([0.1, 0.3, 0.5, 0.7]) for k in ("contour", "infill", "support")}
    ),
    moving=st.booleans(),
    controller=st.sampled_from(["follower", "qsp_speed"]),
)
def test_follower_never_breaks_a_print_cap(floor, tasks, caps, moving, controller):
    # The second job prints on the way back to "a". It reaches the robot at rest at "b" or,
    # when `moving`, while the robot drives home at speed; caps that start while it drives
    # must hold all the same. qsp_speed looks only a braking distance ahead instead of a
    # minute, so a tighter cap is met with the least margin there.
    a, b = floor.station("a"), floor.station("b")
    try:
        trip = PathPlanner(floor, 1.0, 0.5).path((a.x, a.y), (b.x, b.y))
    except NoPathError:
        assume(False)
    note(f"tasks {tasks}, caps {caps}")
    second = ScriptedJob(trip.travel_time + 3.0 if moving else 0.0, "a", tasks=tasks)
    # Long enough for both jobs whatever was drawn: the first trip and the second's release,
    # the trip home under caps (a 0.1 m/s cap makes it 10x slower), and the whole print, on
    # which a robot that arrives first waits. A print longer than the trip used to outlast
    # the run, so the second job could not be delivered.
    print_s = tasks[-1].end_s - tasks[0].start_s
    scenario = Scenario(
        name="property-caps",
        source="<property test>",
        map=Path("<random floor>"),
        duration_s=60.0 + 14.0 * trip.travel_time + print_s,
        robots=(RobotsConfig(count=1, start=("a",), period_s=0.25, radius=0.3),),
        jobs=JobsConfig(mode="scripted", scripted=(ScriptedJob(0.0, "b"), second)),
        print_caps=caps,
        controller=PluginChoice(controller),
    )
    result = World(scenario, floor).run()
    assert result.summary["violations"]["print_speed"] == 0, result.safety.examples
    assert result.summary["violations"]["speed_zone"] == 0, result.safety.examples
    assert result.summary["violations"]["obstacle"] == 0, result.safety.examples
    assert result.summary["jobs"]["completed"] == 2  # not vacuous: it drove while printing

"""Followers never touch, whatever control period the scenario sets (issue 16).

A command is held for a whole period, and every robot decides in the same tick: what a
neighbour does now is not in the plan it sent before. At 0.5 and 1 s that step is 0.18 and
0.7 m (a_max 0.5), more than the follower's margin, and followers collided
(tests/cases/follower_coarse_period). Here small fleets of followers on an empty hall or a
random floor, at random periods and seeds, are judged by a separation check of our own, built
from the run directory's ``trajectories.csv`` alone: at every recorded step, and on the
straight segment to the next, every pair of robots is at least the sum of their radii
apart. Derandomized, like the other property tests.
"""

from __future__ import annotations

import csv
import itertools
import math
import tempfile
from collections import defaultdict
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, note, settings
from hypothesis import strategies as st
from shapely.geometry import box

from fleet.engine import World
from fleet.errors import MapError, NoPathError, ScenarioError
from fleet.floor import Floor, FloorSpec, Station, compile_floor
from fleet.paths import PathPlanner
from fleet.plugins import Neighbour, RobotSpec
from fleet.plugins.robot import neighbour_stray, unseen_step
from fleet.scenario import (
    JobsConfig,
    PluginChoice,
    RobotsConfig,
    Scenario,
    ScriptedJob,
    sensing_needed,
)
from fleet_plugins.follower.yielding import Forecast
from tests.test_properties import random_floor

RADIUS = 0.4


@st.composite
def empty_hall(draw: st.DrawFn) -> Floor:
    """An empty rectangular hall with a depot `a` and a station `b`."""
    w, h = draw(st.floats(12, 30)), draw(st.floats(8, 20))
    a = (draw(st.floats(1, w - 1)), draw(st.floats(1, h - 1)))
    b = (draw(st.floats(1, w - 1)), draw(st.floats(1, h - 1)))
    assume(math.dist(a, b) > 3.0)
    spec = FloorSpec(
        source="<empty hall>",
        name="hall",
        boundary=box(0, 0, w, h),
        default_v_max=(1.0, 1.0),
        clearance=RADIUS,
        obstacles=(),
        zones=(),
        stations=(Station("a", *a, kind="depot"), Station("b", *b)),
    )
    try:
        return compile_floor(spec)
    except MapError:
        assume(False)
        raise  # unreachable: assume(False) raises


def closest_pairs(
    trajectories: Path, radii: dict[str, float]
) -> list[tuple[float, str, str, float]]:
    """From a ``trajectories.csv``: every (t, robot, robot, distance) closer than their radii,
    at a recorded step or on the way to the next (robots move on straight segments at constant
    velocity between steps, so their offset does too: its nearest point to zero)."""
    at: dict[float, dict[str, tuple[float, float]]] = defaultdict(dict)
    with trajectories.open(newline="") as f:
        for row in csv.DictReader(f):
            at[float(row["t"])][row["robot"]] = (float(row["x"]), float(row["y"]))
    times = sorted(at)
    out = []
    for t0, t1 in zip(times, [*times[1:], times[-1]], strict=True):
        now, nxt = at[t0], at[t1]
        for a, b in itertools.combinations(sorted(now), 2):
            dx, dy = now[a][0] - now[b][0], now[a][1] - now[b][1]
            ex, ey = dx, dy
            if a in nxt and b in nxt:
                ex, ey = nxt[a][0] - nxt[b][0], nxt[a][1] - nxt[b][1]
            gx, gy = ex - dx, ey - dy
            g2 = gx * gx + gy * gy
            s = 0.0 if g2 == 0.0 else min(max(-(dx * gx + dy * gy) / g2, 0.0), 1.0)
            d = math.hypot(dx + s * gx, dy + s * gy)
            if d < radii[a] + radii[b]:
                out.append((t0, a, b, d))
    return out


def test_the_separation_check_sees_a_contact(tmp_path: Path) -> None:
    # The oracle itself can fail: two robots 0.5 m apart with radii 0.4 are in contact.
    path = tmp_path / "trajectories.csv"
    head = "t,robot,x,y,vx,vy,region,v_zone\n"
    path.write_text(head + "0.0,r1,1.0,1.0,0,0,0,1\n0.0,r2,1.5,1.0,0,0,0,1\n")
    assert closest_pairs(path, {"r1": 0.4, "r2": 0.4}) == [(0.0, "r1", "r2", 0.5)]
    assert closest_pairs(path, {"r1": 0.2, "r2": 0.2}) == []
    # Two robots that swap places within one step pass through each other between samples.
    rows = ["0.0,r1,0.0,0.0", "0.0,r2,2.0,0.0", "1.0,r1,2.0,0.0", "1.0,r2,0.0,0.0"]
    path.write_text(head + "".join(f"{r},0,0,0,1\n" for r in rows))
    assert closest_pairs(path, {"r1": 0.4, "r2": 0.4}) == [(0.0, "r1", "r2", 0.0)]


def head_on_world(floor: Floor, groups: tuple[RobotsConfig, ...], seed: int, gaps: list[float]):
    """A World of followers in `groups` on `floor` with jobs both ways between stations `a` and
    `b` (each via the other) `gaps` seconds apart, so robots meet head-on; the test is skipped
    (`assume`) when there is no path or no room round a station. A period refused by name must
    be one in which a robot could move more than its diameter unseen."""
    a, b = floor.station("a"), floor.station("b")
    try:
        trip = PathPlanner(floor, 1.0, 0.5).path((a.x, a.y), (b.x, b.y))
    except NoPathError:
        assume(False)
    at, jobs = 0.0, []
    for i, gap in enumerate(gaps):
        at += gap
        via, to = ("a", "b") if i % 2 == 0 else ("b", "a")
        jobs.append(ScriptedJob(at, to, via=(via,)))
    scenario = Scenario(
        name="follower-periods",
        source="<follower period property>",
        map=Path("<random floor>"),
        duration_s=min(40.0 + 3.0 * trip.travel_time, 150.0),
        seed=seed,
        robots=groups,
        controller=PluginChoice("follower"),
        dispatcher=PluginChoice("greedy"),
        jobs=JobsConfig(mode="scripted", scripted=tuple(jobs)),
        # 6 m, or as far as the rule asks for these periods (`sensing_needed`: 6.46 m at 0.5 s)
        sensing_radius_m=max([6.0, *(sensing_needed(g, h) for g in groups for h in groups)]),
        deadlock_after_s=10.0,
    )
    try:
        return World(scenario, floor)
    except ScenarioError as exc:
        fastest = max(g.v_max * g.period_s for g in groups)
        assert not exc.field.endswith("period_s") or fastest > 2 * RADIUS, exc
        assume(False)
        raise  # unreachable: assume(False) raises


def contacts_of(world: World) -> tuple[list, int]:
    """The contacts in `world`'s written trajectories.csv (`closest_pairs`), and its rows."""
    with tempfile.TemporaryDirectory() as out:
        world.write(Path(out))
        path = Path(out) / "trajectories.csv"
        return closest_pairs(path, dict.fromkeys(world.robots, RADIUS)), (
            path.read_text().count("\n") - 1
        )


@settings(
    max_examples=16, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    floor=st.one_of(empty_hall(), random_floor()),
    robots=st.integers(2, 4),
    period=st.sampled_from([0.1, 0.25, 0.4, 0.5, 0.75, 1.0]),
    seed=st.integers(0, 1000),
    gaps=st.lists(st.floats(0.0, 8.0), min_size=3, max_size=6),
)
def test_followers_never_touch_at_any_period(
    floor: Floor, robots: int, period: float, seed: int, gaps: list[float]
) -> None:
    note(f"period {period} s, {robots} robots, seed {seed}")
    group = RobotsConfig(count=robots, start=("a", "b"), radius=RADIUS, period_s=period)
    world = head_on_world(floor, (group,), seed, gaps)
    summary = world.run().summary
    contacts, rows = contacts_of(world)
    assert rows >= robots * world.scenario.duration_s / period  # every robot at every step
    assert contacts == []
    assert summary["distance_m"] >= 1.0  # not vacuous: the robots drove


@settings(
    max_examples=8, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    floor=st.one_of(empty_hall(), random_floor()),
    periods=st.lists(st.sampled_from([0.1, 0.25, 0.5, 1.0]), min_size=2, max_size=2, unique=True),
    seed=st.integers(0, 1000),
    gaps=st.lists(st.floats(0.0, 6.0), min_size=3, max_size=5),
)
def test_followers_of_mixed_periods_never_touch(
    floor: Floor, periods: list[float], seed: int, gaps: list[float]
) -> None:
    # A neighbour's period is not in its observation: each robot forecasts with its own.
    note(f"periods {periods} s, seed {seed}")
    groups = tuple(
        RobotsConfig(count=2, start=("a", "b"), radius=RADIUS, period_s=p) for p in periods
    )
    world = head_on_world(floor, groups, seed, gaps)
    summary = world.run().summary
    contacts, _ = contacts_of(world)
    assert contacts == []
    assert summary["distance_m"] >= 1.0


@settings(
    max_examples=8, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(
    floor=st.one_of(empty_hall(), random_floor()),
    limits=st.lists(
        st.tuples(
            st.sampled_from([0.3, 0.6, 1.0, 1.6]),  # v_max
            st.sampled_from([0.3, 0.5, 1.0, 2.0]),  # a_max
            st.sampled_from([0.25, 0.5, 1.0]),  # period_s
        ),
        min_size=2,
        max_size=2,
        unique=True,
    ),
    seed=st.integers(0, 1000),
    gaps=st.lists(st.floats(0.0, 6.0), min_size=3, max_size=5),
)
def test_followers_of_mixed_limits_never_touch(
    floor: Floor, limits: list[tuple[float, float, float]], seed: int, gaps: list[float]
) -> None:
    note(f"limits (v_max, a_max, period) {limits}, seed {seed}")
    groups = tuple(
        RobotsConfig(count=2, start=("a", "b"), radius=RADIUS, v_max=v, a_max=a, period_s=p)
        for v, a, p in limits
    )
    world = head_on_world(floor, groups, seed, gaps)
    summary = world.run().summary
    contacts, _ = contacts_of(world)
    assert contacts == []
    assert summary["distance_m"] >= 1.0


def test_a_neighbour_strays_and_brakes_by_its_own_limits():
    # A slow, gentle observer and a fast, sharp neighbour: the neighbour's unseen step is its
    # own (a_max 2 over its 0.5 s period: up to 0.71 m), not the observer's (2.7 cm).
    own = RobotSpec(v_max=0.6, a_max=0.3, radius=0.4, period=0.25)
    told = Neighbour("r2", 0.0, 0.0, 1.2, 0.0, 0.4, 0, (), v_max=1.6, a_max=2.0, period=0.5)
    unknown = Neighbour("r2", 0.0, 0.0, 1.2, 0.0, 0.4, 0, ())
    assert neighbour_stray(unknown, own) == unseen_step(0.25, 0.3, 0.6)
    assert neighbour_stray(told, own) == unseen_step(0.5, 2.0, 1.6) == math.sqrt(2.0) * 0.5
    # Over the longer period of the two: a fast-ticking neighbour seen by a slow observer.
    quick = Neighbour("r2", 0.0, 0.0, 0.0, 0.0, 0.4, 0, (), a_max=0.3, period=0.1)
    slow = RobotSpec(v_max=0.6, a_max=0.3, radius=0.4, period=1.0)
    assert neighbour_stray(quick, slow) == unseen_step(1.0, 0.3, 0.6)
    # The forecast keeps that much, and the neighbour's braking (no plan) ends where its own
    # bound stops it: 1.2 m/s held over its 0.5 s step, then braking at 2 m/s^2 (1.2 -> 0.2 ->
    # 0): 0.6 + 0.6 + 0.1 = 1.3 m, where the observer's own bound (0.3) would say over 2 m.
    f = Forecast.of(told, 0.0, own.period, own.a_max, own.v_max)
    assert f.slack == neighbour_stray(told, own)
    assert f.reach[2] == pytest.approx(1.3)
    assert Forecast.of(unknown, 0.0, own.period, own.a_max, own.v_max).reach[2] > 2.0


def test_the_engine_tells_each_neighbour_its_limits():
    spec = FloorSpec(
        source="<hall>",
        name="hall",
        boundary=box(0, 0, 20, 10),
        default_v_max=(1.0, 1.0),
        clearance=RADIUS,
        obstacles=(),
        zones=(),
        stations=(Station("a", 3.0, 5.0, kind="depot"), Station("b", 6.0, 5.0)),
    )
    groups = (
        RobotsConfig(count=1, start=("a",), radius=RADIUS, v_max=0.6, a_max=0.3, period_s=0.25),
        RobotsConfig(count=1, start=("b",), radius=RADIUS, v_max=1.6, a_max=2.0, period_s=0.5),
    )
    scenario = Scenario(
        name="mixed",
        source="<mixed limits>",
        map=Path("<hall>"),
        duration_s=10.0,
        seed=1,
        robots=groups,
        controller=PluginChoice("follower"),
        dispatcher=PluginChoice("greedy"),
        sensing_radius_m=max(sensing_needed(g, h) for g in groups for h in groups),
    )
    world = World(scenario, compile_floor(spec))
    seen = {o.robot: o.neighbours for o in world.sensing.observe(list(world.robots.values()), 0.0)}
    (slow_sees,), (fast_sees,) = (seen[r] for r in sorted(seen))
    assert (slow_sees.v_max, slow_sees.a_max, slow_sees.period) == (1.6, 2.0, 0.5)
    assert (fast_sees.v_max, fast_sees.a_max, fast_sees.period) == (0.6, 0.3, 0.25)

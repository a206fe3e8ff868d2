"""The MPC controller in closed loop with real HiGHS solves: zone limits and print caps that
bind, obstacles, fallbacks, options, both model interfaces, solve reports and the engine.

Every closed loop here is driven by hand: the controller is asked once per tick, the paper's
double integrator (`fleet.plugins.robot.DoubleIntegrator`, which clips the input) moves the
robot, and the recorded trajectory is judged by the safety checker (`fleet.engine.safety`),
never by the controller's own plan.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, assume, given, note, settings
from hypothesis import strategies as st
from shapely.geometry import Polygon, box

from fleet.engine import World
from fleet.engine.safety import check_print_speed, check_steps
from fleet.errors import MapError, NoPathError, PluginError
from fleet.floor import Floor, FloorSpec, Obstacle, SpeedZone, compile_floor
from fleet.floor.mapfile import grow
from fleet.paths import PathPlanner
from fleet.plugins import (
    CAP_LOOKAHEAD_S,
    Command,
    ControllerContext,
    ControlStatus,
    Observation,
    RobotSpec,
    SolverOutcome,
    load_controller,
)
from fleet.plugins.robot import DoubleIntegrator, brake_input
from fleet.plugins.testing import CONFORMANCE_SPEC, check_controller, conformance_floor
from fleet.printing import CapSchedule
from fleet.scenario import load_scenario
from fleet_plugins.mpc import MPCController

ROOT = Path(__file__).resolve().parents[1]

#: A robot as in the paper's case study (dt = 1 s) and one with a finer period.
SPEC_1S = RobotSpec(v_max=1.0, a_max=0.5, radius=0.4, period=1.0)
SPEC_HALF = RobotSpec(v_max=1.0, a_max=0.5, radius=0.4, period=0.5)
ARRIVAL_M = 0.05  # as the brief's closed loop and the paper scenarios: at rest within 5 cm
REST = 1e-9  # m/s per axis: at rest
BIND = 1e-6  # m/s: "binds" = reaches the limit within the checker's own speed tolerance

Goal = tuple[float, float]


# --- floors ---------------------------------------------------------------------------------------


def corridor(zone: tuple[float, float] | None = None, limit: float = 0.3) -> Floor:
    """A 20 x 4 m corridor, optionally with a slow zone x in `zone` across its whole width."""
    pieces = [(box(0, 0, 20, 4), (1.0, 1.0), None)]
    zones = ()
    if zone is not None:
        x0, x1 = zone
        zones = (SpeedZone("slow", box(x0, 0, x1, 4), (limit, limit)),)
        pieces = [
            (box(0, 0, x0, 4), (1.0, 1.0), None),
            (box(x0, 0, x1, 4), (limit, limit), "slow"),
            (box(x1, 0, 20, 4), (1.0, 1.0), None),
        ]
    spec = FloorSpec(
        source="<test corridor>",
        name="corridor",
        boundary=box(0, 0, 20, 4),
        default_v_max=(1.0, 1.0),
        zones=zones,
    )
    return Floor.from_regions(spec, pieces)


#: An L-shaped machine in a 20 x 10 m hall, right across the straight line (2, 5) -> (18, 5).
L_MACHINE = Polygon([(8, 1), (12, 1), (12, 3), (10, 3), (10, 9), (8, 9)])


def l_hall(zone: bool = False) -> Floor:
    """The hall with `L_MACHINE` (decomposed by the real floor compiler), optionally with a
    0.4 m/s zone hugging the machine."""
    zones = ()
    if zone:
        zones = (
            SpeedZone("buffer", grow(L_MACHINE, 1.0).intersection(box(0, 0, 20, 10)), (0.4, 0.4)),
        )
    spec = FloorSpec(
        source="<test L hall>",
        name="L hall",
        boundary=box(0, 0, 20, 10),
        default_v_max=(1.0, 1.0),
        obstacles=(Obstacle("L", L_MACHINE),),
        zones=zones,
    )
    return compile_floor(spec)


CORRIDOR = corridor()
L_HALL = l_hall()


# --- the closed loop ------------------------------------------------------------------------------


@dataclass
class Loop:
    """One MPC, one simulated robot, and everything that happened, tick by tick."""

    controller: MPCController
    floor: Floor
    spec: RobotSpec
    caps: CapSchedule = field(default_factory=CapSchedule)
    p: np.ndarray = field(default_factory=lambda: np.zeros(2))
    v: np.ndarray = field(default_factory=lambda: np.zeros(2))
    tick: int = 0
    t: list[float] = field(default_factory=list)
    xy: list[np.ndarray] = field(default_factory=list)
    vel: list[np.ndarray] = field(default_factory=list)
    observations: list[Observation] = field(default_factory=list)
    commands: list[Command] = field(default_factory=list)

    @classmethod
    def start(
        cls,
        controller: MPCController,
        floor: Floor,
        at: Goal,
        spec: RobotSpec = SPEC_1S,
        *,
        caps: CapSchedule | None = None,
        planner: PathPlanner | None = None,
    ) -> Loop:
        """Reset `controller` for a robot at rest at `at` (`planner` defaults to `floor`'s)."""
        planner = planner or PathPlanner(floor, spec.v_max, spec.a_max)
        controller.reset(ControllerContext("r1", spec, floor, planner))
        loop = cls(controller, floor, spec, caps or CapSchedule())
        loop.p = np.array(at, dtype=float)
        return loop

    @property
    def now(self) -> float:
        return self.tick * self.spec.period

    def observe(self, goal: Goal | None) -> Observation:
        """This tick's observation, with the print caps as the engine would list them."""
        t, dt = self.now, self.spec.period
        here = self.caps.cap_over(t, t + dt)
        return Observation(
            "r1", self.tick, t, *map(float, self.p), *map(float, self.v), goal=goal,
            speed_cap=None if math.isinf(here) else here,
            speed_caps=self.caps.window(t, t + CAP_LOOKAHEAD_S).pieces,
        )  # fmt: skip

    def step(self, goal: Goal | None) -> Command:
        """Ask the controller, record the state, integrate (the integrator clips the input)."""
        obs = self.observe(goal)
        cmd = self.controller.compute(obs)
        a_max = self.spec.a_max
        assert max(abs(cmd.ax), abs(cmd.ay)) <= a_max + 1e-9, cmd
        self.observations.append(obs)
        self.commands.append(cmd)
        self.t.append(self.now)
        self.xy.append(self.p.copy())
        self.vel.append(self.v.copy())
        robot = DoubleIntegrator(self.spec.period, a_max)
        x, y, vx, vy = robot.step(*self.p, *self.v, cmd.ax, cmd.ay)
        self.p, self.v = np.array([x, y]), np.array([vx, vy])
        self.tick += 1
        return cmd

    def arrived(self, goal: Goal) -> bool:
        return math.dist(self.p, goal) <= ARRIVAL_M and float(np.max(np.abs(self.v))) <= REST

    def drive(self, goal: Goal, limit: int) -> bool:
        """Step towards `goal` until at rest near it (True) or `limit` ticks (False)."""
        for _ in range(limit):
            if self.arrived(goal):
                return True
            self.step(goal)
        return self.arrived(goal)

    def trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Times, positions and velocities, including the current state."""
        return (
            np.array([*self.t, self.now]),
            np.array([*self.xy, self.p]),
            np.array([*self.vel, self.v]),
        )

    def violations(self) -> list[str]:
        """Obstacle, zone-speed and print-speed violations as the safety checker sees them."""
        t, xy, v = self.trajectory()
        found = check_steps(self.floor, t, xy, v, "r1") + check_print_speed(t, xy, v, self.caps)
        return [f"{x.kind} at t={x.t:g} ({x.x:.4g}, {x.y:.4g}): {x.detail}" for x in found]

    def path_length(self) -> float:
        _, xy, _ = self.trajectory()
        return float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))


def step_limits(loop: Loop) -> np.ndarray:
    """Per-axis zone limit of every recorded step (the planner's judgement of the segment)."""
    planner = PathPlanner(loop.floor, loop.spec.v_max, loop.spec.a_max)
    _, xy, _ = loop.trajectory()
    limits = [planner.speed_limit(xy[k], xy[k + 1]) for k in range(len(xy) - 1)]
    assert all(lim is not None for lim in limits)
    return np.array(limits)


# --- 1. zone limits -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("spec", "zone", "blind_planner"),
    [
        # The path layer's reference itself crosses at the limit: the MPC tracks it exactly.
        pytest.param(SPEC_HALF, (8.0, 12.0), False, id="reference-at-the-limit"),
        # The reference is planned as if the zone were not there (1 m/s straight through), so
        # only the MILP's Big-M speed rows hold the robot to the zone's limit.
        pytest.param(SPEC_1S, (8.0, 12.0), True, id="milp-rows-alone"),
    ],
)
def test_a_slow_zone_across_the_corridor_is_crossed_at_exactly_its_limit(
    spec: RobotSpec, zone: tuple[float, float], blind_planner: bool
) -> None:
    floor = corridor(zone, limit=0.3)
    planner = PathPlanner(CORRIDOR, spec.v_max, spec.a_max) if blind_planner else None
    loop = Loop.start(MPCController(horizon=10), floor, (2.0, 2.0), spec, planner=planner)
    assert loop.drive((18.0, 2.0), limit=round(120 / spec.period))

    assert loop.violations() == []
    _, _, v = loop.trajectory()
    limits = step_limits(loop)
    in_zone = limits[:, 0] < 1.0
    assert in_zone.sum() >= 10  # it really crossed the 4 m zone, slowly
    # It binds: as fast as allowed inside the zone, and faster outside it.
    assert np.max(np.abs(v[:-1][in_zone, 0])) == pytest.approx(0.3, abs=BIND)
    assert np.max(np.abs(v[:-1][~in_zone, 0])) > 0.6
    assert np.max(np.abs(v[:, 1])) <= 1e-9  # straight down the corridor


# --- 2. print caps --------------------------------------------------------------------------------


def test_a_print_cap_binds_and_the_robot_brakes_before_it_starts() -> None:
    spec, cap, start_s, end_s = SPEC_HALF, 0.25, 5.0, 15.0
    caps = CapSchedule(((start_s, end_s, cap),))
    loop = Loop.start(MPCController(horizon=10), CORRIDOR, (2.0, 2.0), spec, caps=caps)
    assert loop.drive((18.0, 2.0), limit=120)

    assert loop.violations() == []
    t, _, v = loop.trajectory()
    speed = np.max(np.abs(v[:-1]), axis=1)
    steps = t[:-1]
    under = (steps + spec.period > start_s) & (steps < end_s)  # steps overlapping the piece
    assert under.sum() == round((end_s - start_s) / spec.period)
    assert np.max(speed[under]) == pytest.approx(cap, abs=BIND)  # binds
    before = steps < start_s
    peak = int(np.argmax(np.where(before, speed, -1.0)))
    # Faster than the cap before the piece, then slowing down *before* it starts: the cap was
    # known a horizon ahead, so the first capped step is already within it.
    assert speed[peak] > cap + spec.a_max * spec.period
    first = int(np.flatnonzero(under)[0])
    assert np.all(np.diff(speed[peak : first + 1]) <= 1e-12)
    assert speed[first - 1] < speed[peak] and speed[first] <= cap + BIND
    # And free again after the piece.
    assert np.max(speed[steps >= end_s]) > cap + 0.2


def test_a_cap_at_the_start_of_a_trip_does_not_make_the_first_solves_infeasible() -> None:
    # A region boundary (a 0.8 m/s zone) 1 m ahead; 0.2 m/s for the first 30 s.
    floor = corridor((3.0, 6.0), limit=0.8)
    caps = CapSchedule(((0.0, 30.0, 0.2),))
    # Every tick solves (reuse_ticks = 0): each of the first solves is checked.
    controller = MPCController(horizon=8, reuse_ticks=0)
    loop = Loop.start(controller, floor, (2.0, 2.0), SPEC_HALF, caps=caps)
    for _ in range(10):
        loop.step((18.0, 2.0))
    assert loop.violations() == []
    assert [c.solve.outcome for c in loop.commands] == [SolverOutcome.OPTIMAL] * 10  # type: ignore[union-attr]
    assert loop.p[0] > 2.5  # 5 s at up to 0.2 m/s


# --- 3. obstacles ---------------------------------------------------------------------------------


def test_an_l_shaped_machine_between_start_and_goal_is_driven_around() -> None:
    start, goal = (2.0, 5.0), (18.0, 5.0)
    assert shapely.LineString([start, goal]).intersects(L_MACHINE)  # the straight way is shut
    loop = Loop.start(MPCController(horizon=10), L_HALL, start, SPEC_1S)
    assert loop.drive(goal, limit=120)

    assert loop.violations() == []
    assert loop.path_length() > math.dist(start, goal) + 1.0
    # Every sample is outside the machine (not just "no violation reported").
    _, xy, _ = loop.trajectory()
    assert not np.any(shapely.intersects(L_MACHINE.buffer(-1e-6), shapely.points(xy)))


# --- 4. fallbacks ---------------------------------------------------------------------------------

FAILED = {SolverOutcome.NO_SOLUTION, SolverOutcome.FEASIBLE, SolverOutcome.TIME_LIMIT}


def starve(controller: MPCController) -> None:
    """Give the controller's current trip model (and every new one) a 1 us wall-clock guard."""
    controller.time_limit_s = 1e-6  # read when the next trip's model is built
    model = controller._model
    assert model is not None
    model.time_limit_s = 1e-6  # read by every solve


@pytest.mark.parametrize("interface", ["direct", "pyomo"])
def test_a_tiny_time_limit_falls_back_every_tick_and_stays_safe(interface: str) -> None:
    controller = MPCController(horizon=8, time_limit_s=1e-6, interface=interface)
    loop = Loop.start(controller, CORRIDOR, (2.0, 2.0), SPEC_HALF)
    for _ in range(20):
        loop.step((18.0, 2.0))

    outcomes = {c.solve.outcome for c in loop.commands if c.solve is not None}
    assert outcomes <= FAILED and len(outcomes) > 0
    fallbacks = [c for c in loop.commands if c.status is ControlStatus.FALLBACK]
    assert fallbacks
    assert all(c.solve.outcome is SolverOutcome.TIME_LIMIT for c in fallbacks)  # type: ignore[union-attr]
    assert loop.violations() == []
    _, xy, _ = loop.trajectory()
    assert all(CORRIDOR.is_free(*p) for p in xy)


@pytest.mark.parametrize("interface", ["direct", "pyomo"])
def test_a_failed_solve_on_the_plan_walks_down_the_shifted_plan_to_rest(interface: str) -> None:
    dt, goal = SPEC_HALF.period, (18.0, 2.0)
    # No warm start: otherwise the shifted plan is HiGHS's incumbent and the solve "succeeds".
    # reuse_ticks = 0: a tick that followed its plan would not solve, so not fail.
    controller = MPCController(horizon=8, warm_start=False, interface=interface, reuse_ticks=0)
    loop = Loop.start(controller, CORRIDOR, (2.0, 2.0), SPEC_HALF)
    for _ in range(6):
        assert loop.step(goal).status is ControlStatus.OK
    plan = loop.commands[-1].plan
    assert len(plan) == 9 and loop.v[0] > 0.5  # moving at speed when the solver starts failing
    starve(controller)

    for k in range(1, 12):
        expected = (plan[k:] + (plan[-1],) * k)[:9]  # moved on k steps, held at its end
        assert np.allclose(loop.p, plan[min(k, 8)][1:], rtol=0, atol=1e-6)
        cmd = loop.step(goal)
        assert cmd.status is ControlStatus.FALLBACK
        assert cmd.solve is not None and cmd.solve.outcome is SolverOutcome.TIME_LIMIT
        got = np.array(cmd.plan)
        np.testing.assert_allclose(got[:, 0], loop.t[-1] + dt * np.arange(9), atol=1e-9)
        np.testing.assert_allclose(got[:, 1:], np.array(expected)[:, 1:], rtol=0, atol=1e-9)
    assert np.max(np.abs(loop.v)) <= 1e-9  # the plan ended at rest, so the robot did too
    assert loop.violations() == []

    controller.time_limit_s = 1.0  # the solver recovers: the next trip plans from here
    assert loop.drive(goal, limit=80)
    assert loop.commands[-1].status is ControlStatus.OK
    assert loop.violations() == []


def test_a_failed_solve_off_the_plan_brakes_along_the_line_of_travel() -> None:
    goal = (18.0, 5.0)
    controller = MPCController(horizon=8, warm_start=False)
    loop = Loop.start(controller, L_HALL, (2.0, 5.0), SPEC_HALF)
    for _ in range(8):
        loop.step(goal)
    starve(controller)
    loop.p = loop.p + 1e-3  # pushed off the plan (more than the 1e-6 the plan match allows)
    vx, vy = map(float, loop.v)
    assert math.hypot(vx, vy) > 0.5
    cmd = loop.step(goal)
    assert (cmd.ax, cmd.ay) == brake_input(vx, vy, SPEC_HALF.period, SPEC_HALF.a_max)
    assert cmd.status is ControlStatus.FALLBACK and cmd.plan == ()
    assert cmd.solve is not None and cmd.solve.outcome is SolverOutcome.TIME_LIMIT


@pytest.mark.parametrize("limit", ["nodes", "wall clock"])
def test_with_a_warm_start_a_starved_solve_keeps_the_shifted_plan_as_its_answer(limit: str) -> None:
    goal = (18.0, 2.0)
    controller = MPCController(horizon=8, warm_start=True, interface="direct", reuse_ticks=0)
    loop = Loop.start(controller, CORRIDOR, (2.0, 2.0), SPEC_HALF)
    for _ in range(6):
        loop.step(goal)
    plan = loop.commands[-1].plan
    if limit == "nodes":
        assert controller._model is not None
        controller._model.max_nodes = 0  # stopped before the root (the option allows >= 1)
    else:
        starve(controller)
    for k in range(1, 5):
        cmd = loop.step(goal)
        assert cmd.solve is not None
        if limit == "nodes":
            # The MIP start is an incumbent: stopped at the work limit with it, used as is.
            assert cmd.solve.outcome is SolverOutcome.FEASIBLE
            assert cmd.status is ControlStatus.OK
        else:
            # The wall-clock guard's incumbent is not used (it depends on the machine's
            # speed): the fallback follows the same shifted plan.
            assert cmd.solve.outcome is SolverOutcome.TIME_LIMIT
            assert cmd.status is ControlStatus.FALLBACK
        np.testing.assert_allclose(
            np.array(cmd.plan)[:, 1:], np.array((plan[k:] + (plan[-1],) * k)[:9])[:, 1:], atol=1e-9
        )


@pytest.mark.parametrize("interface", ["direct", "pyomo"])
def test_solver_failures_every_few_ticks_around_a_machine_stay_safe_and_arrive(
    interface: str,
) -> None:
    start, goal = (2.0, 5.0), (18.0, 5.0)
    floor = l_hall(zone=True)
    # reuse_ticks = 0: a tick that followed its plan would not solve, so not fail.
    controller = MPCController(horizon=8, warm_start=False, interface=interface, reuse_ticks=0)
    loop = Loop.start(controller, floor, start, SPEC_1S)
    for _ in range(150):
        if loop.arrived(goal):
            break
        if loop.tick % 4 == 3 and controller._model is not None:
            model = controller._model
            model.time_limit_s = 1e-6
        loop.step(goal)
    assert loop.arrived(goal)
    assert loop.violations() == []
    fallbacks = [c for c in loop.commands if c.status is ControlStatus.FALLBACK]
    assert len(fallbacks) >= 5
    assert {c.solve.outcome for c in fallbacks} <= FAILED  # type: ignore[union-attr]


# --- 5. random floors -----------------------------------------------------------------------------


@st.composite
def star_polygon(draw: st.DrawFn, cx: float, cy: float) -> Polygon:
    """A simple, often non-convex polygon: jittered angles around a centre, random radii."""
    n = draw(st.integers(3, 7))
    jitter = draw(st.lists(st.floats(-0.4, 0.4), min_size=n, max_size=n))
    radii = draw(st.lists(st.floats(0.8, 3.0), min_size=n, max_size=n))
    angles = [2 * math.pi * (i + j) / n for i, j in enumerate(jitter)]
    return Polygon(
        [(cx + r * math.cos(a), cy + r * math.sin(a)) for a, r in zip(angles, radii, strict=True)]
    )


@st.composite
def random_trip(draw: st.DrawFn) -> tuple[Floor, Goal, Goal, CapSchedule]:
    """A random floor (non-convex machines, zones around them and free-standing), a reachable
    start and goal, and a random print-cap schedule."""
    w, h = draw(st.floats(16, 26)), draw(st.floats(10, 18))
    obstacles = []
    for i in range(draw(st.integers(1, 3))):
        cx, cy = draw(st.floats(4, w - 4)), draw(st.floats(4, h - 4))
        obstacles.append(Obstacle(f"m{i}", draw(star_polygon(cx, cy))))
    zones = []
    for i, ob in enumerate(obstacles):
        if draw(st.booleans()):
            v = draw(st.sampled_from([0.2, 0.4, 0.6]))
            ring = grow(ob.polygon, 1.0).intersection(box(0, 0, w, h))
            zones.append(SpeedZone(f"buffer{i}", ring, (v, v)))
    if draw(st.booleans()):
        x0, y0 = draw(st.floats(0, w - 3)), draw(st.floats(0, h - 3))
        x1, y1 = x0 + draw(st.floats(2, 8)), y0 + draw(st.floats(2, 6))
        vx, vy = draw(st.sampled_from([0.3, 0.5])), draw(st.sampled_from([0.3, 0.5]))
        zones.append(SpeedZone("zone", box(x0, y0, min(x1, w), min(y1, h)), (vx, vy)))
    spec = FloorSpec(
        source="<random floor>",
        name="random",
        boundary=box(0, 0, w, h),
        default_v_max=(1.0, 1.0),
        clearance=draw(st.sampled_from([0.0, 0.3])),
        obstacles=tuple(obstacles),
        zones=tuple(zones),
    )
    try:
        floor = compile_floor(spec)
    except MapError:
        assume(False)
    point = st.tuples(st.floats(1, w - 1), st.floats(1, h - 1))
    start, goal = draw(point), draw(point)
    assume(floor.is_free(*start) and floor.is_free(*goal) and math.dist(start, goal) > 2.0)
    pieces, t = [], 0.0
    for _ in range(draw(st.integers(0, 2))):
        t += draw(st.floats(0, 15))
        length = draw(st.floats(2, 12))
        pieces.append((t, t + length, draw(st.sampled_from([0.2, 0.3, 0.5]))))
        t += length
    return floor, start, goal, CapSchedule(tuple(pieces))


def random_run(
    trip: tuple[Floor, Goal, Goal, CapSchedule], spec: RobotSpec, horizon: int
) -> tuple[Loop, bool]:
    """Drive one random trip (noting the floor for a failure report); whether it arrived."""
    floor, start, goal, caps = trip
    note(f"boundary {floor.spec.boundary.wkt}, clearance {floor.spec.clearance}")
    note("obstacles " + "; ".join(o.polygon.wkt for o in floor.spec.obstacles))
    note("zones " + "; ".join(f"{z.v_max} {z.polygon.wkt}" for z in floor.spec.zones))
    note(f"start {start!r} goal {goal!r} caps {caps.pieces!r} dt {spec.period} N {horizon}")
    planner = PathPlanner(floor, spec.v_max, spec.a_max)
    try:
        ref = planner.reference(start, goal, dt=spec.period)
    except NoPathError:
        assume(False)
    loop = Loop.start(MPCController(horizon=horizon), floor, start, spec, caps=caps)
    capped_s = sum(end - begin for begin, end, _ in caps.pieces)
    limit = math.ceil((2.0 * ref.duration + 3.0 * capped_s + 30.0) / spec.period)
    return loop, loop.drive(goal, limit)


SPECS = st.sampled_from([SPEC_HALF, SPEC_1S])
HORIZONS = st.sampled_from([8, 10])


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(trip=random_trip(), spec=SPECS, horizon=HORIZONS)
def test_on_random_floors_the_mpc_never_breaks_a_rule(
    trip: tuple[Floor, Goal, Goal, CapSchedule], spec: RobotSpec, horizon: int
) -> None:
    loop, _ = random_run(trip, spec, horizon)
    assert loop.violations() == []


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(trip=random_trip(), spec=SPECS, horizon=HORIZONS)
def test_on_random_floors_the_mpc_arrives(
    trip: tuple[Floor, Goal, Goal, CapSchedule], spec: RobotSpec, horizon: int
) -> None:
    loop, arrived = random_run(trip, spec, horizon)
    assert arrived, f"at {loop.p} moving {loop.v} after {loop.now:g} s"
    assert loop.violations() == []


def test_a_cap_while_rounding_a_machine_does_not_strand_the_robot() -> None:
    # The path goes over the L's top; 0.2 m/s from 6 s to 21 s, while approaching it.
    caps = CapSchedule(((6.0, 21.0, 0.2),))
    loop = Loop.start(MPCController(horizon=8), L_HALL, (2.0, 9.5), SPEC_1S, caps=caps)
    arrived = loop.drive((18.0, 2.0), limit=100)
    assert loop.violations() == []
    assert arrived, f"stuck at {loop.p}"


#: A floor hypothesis found (two near-identical machines): the MPC never leaves (2.37, 1.0).
_TWIN_MACHINES = (
    "POLYGON ((10.257661841664117 3.7610837815257936, 8.648705460809364 5.1939614397573175, "
    "7.7293317086467885 7.319337307735589, 6.635340514605565 5.083552337632639, "
    "5.660453218868148 3.494422444083245, 7.621983252834948 3.7448315398822323, "
    "8.298791841486986 3.8993086836532673, 10.257661841664117 3.7610837815257936))",
    "POLYGON ((6.457661841664118 3.2363099118981022, 4.673863256039617 4.844997796081927, "
    "3.9293317086467887 6.7945634381078985, 2.8353405146055644 4.558778468004948, "
    "1.8604532188681482 2.9696485744555536, 3.8219832528349484 3.220057670254541, "
    "4.4987918414869865 3.374534814025576, 6.457661841664118 3.2363099118981022))",
    "POLYGON ((6.457661841664118 3.2363099118981022, 4.848705460809364 4.669187570129626, "
    "3.9293317086467887 6.7945634381078985, 2.8353405146055644 4.558778468004948, "
    "1.8604532188681482 2.9696485744555536, 3.8219832528349484 3.220057670254541, "
    "4.4987918414869865 3.374534814025576, 6.457661841664118 3.2363099118981022))",
)


def test_a_trip_past_twin_machines_gets_going() -> None:
    spec = FloorSpec(
        source="<hypothesis floor>",
        name="twin machines",
        boundary=box(0, 0, 23.305207245601448, 10.107714867842587),
        default_v_max=(1.0, 1.0),
        obstacles=tuple(
            Obstacle(f"m{i}", shapely.from_wkt(w)) for i, w in enumerate(_TWIN_MACHINES)
        ),
    )
    floor = compile_floor(spec)
    loop = Loop.start(MPCController(horizon=8), floor, (2.3747177703409603, 1.0), SPEC_HALF)
    for _ in range(10):
        loop.step((1.0, 7.0))
    assert loop.violations() == []
    assert [c.status for c in loop.commands] == [ControlStatus.OK] * 10


# --- 6. conformance -------------------------------------------------------------------------------


def test_the_mpc_passes_the_conformance_check() -> None:
    check_controller(MPCController, options={"horizon": 10})


def test_a_horizon_shorter_than_braking_from_full_speed_is_refused() -> None:
    # Every plan ends at rest: at dt = 0.25 s a 5-step horizon never let the robot leave its
    # start (the plan could not reach a useful speed and stop again within 1.25 s).
    floor, spec = conformance_floor(), CONFORMANCE_SPEC
    planner = PathPlanner(floor, spec.v_max, spec.a_max)
    context = ControllerContext("r1", spec, floor, planner)
    with pytest.raises(ValueError, match=r"horizon 5 x period 0.25 s = 1.25 s is shorter"):
        MPCController(horizon=5).reset(context)
    loop = Loop.start(MPCController(horizon=8), floor, (2.0, 5.0), spec)
    for _ in range(40):
        loop.step((18.0, 7.0))
    assert math.dist(loop.p, (2.0, 5.0)) > 1.0


# --- 7. options -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("horizon", 1),
        ("horizon", 10.0),
        ("horizon", True),
        ("interface", "x"),
        ("time_limit_s", 0),
        ("time_limit_s", float("inf")),
        ("max_nodes", 0),
        ("max_nodes", 2.5),
        ("max_nodes", True),
        ("max_nodes", 2**31),
        ("max_nodes", "100"),
        ("q_position", -1),
        ("q_velocity", float("nan")),
        ("r_input", "1"),
        ("corridor", -1),
        ("corridor_steps", -1),
        ("corridor_steps", 2.0),
        ("warm_start", "yes"),
    ],
)
def test_a_bad_option_is_refused_naming_the_option_and_the_value(
    option: str, value: object
) -> None:
    with pytest.raises(ValueError, match=f"{option} = {re.escape(repr(value))}: must"):
        MPCController(**{option: value})  # type: ignore[arg-type]
    with pytest.raises(PluginError, match=f"'mpc'.*{option}"):
        load_controller("mpc", {option: value})


def test_far_steps_get_only_the_progress_s_chords_and_the_robot_still_turns_the_corner() -> None:
    # Round the L machine (several regions on the way): steps after `corridor_steps` lose the
    # corridor's extra chords, so the solves carry fewer binaries; the plan still has room to
    # go round the machine and arrive safely.
    goal = (18.0, 5.0)
    binaries = {}
    for steps in (0, 3, 8):
        loop = Loop.start(MPCController(horizon=8, corridor_steps=steps), L_HALL, (2.0, 5.0))
        assert loop.drive(goal, limit=80), steps
        assert loop.violations() == []
        binaries[steps] = np.mean(loop.controller.binaries)
    # 8 = the horizon: every step gets the corridor, as before the option.
    assert binaries[0] < binaries[3] < binaries[8]


def test_a_horizon_reaching_past_the_cap_look_ahead_is_refused_in_reset() -> None:
    too_long = math.floor(CAP_LOOKAHEAD_S / SPEC_1S.period) + 1
    planner = PathPlanner(CORRIDOR, SPEC_1S.v_max, SPEC_1S.a_max)
    context = ControllerContext("r1", SPEC_1S, CORRIDOR, planner)
    with pytest.raises(ValueError, match=rf"horizon {too_long} x period 1 s = {too_long} s"):
        MPCController(horizon=too_long).reset(context)
    MPCController(horizon=too_long - 1).reset(context)  # exactly the look-ahead is fine


def test_is_registered_as_mpc_with_the_papers_defaults() -> None:
    mpc = load_controller("mpc")
    assert isinstance(mpc, MPCController)
    assert (mpc.horizon, mpc.weights, mpc.interface.value) == (25, (1.0, 1.0, 1.0), "direct")


# --- 8. the two interfaces ------------------------------------------------------------------------


def test_the_pyomo_and_direct_interfaces_give_the_same_commands() -> None:
    start, goal = (2.0, 5.0), (18.0, 5.0)
    floor = l_hall(zone=True)
    direct = Loop.start(MPCController(horizon=8, interface="direct"), floor, start, SPEC_1S)
    pyomo = MPCController(horizon=8, interface="pyomo")
    pyomo.reset(ControllerContext("r1", SPEC_1S, floor, PathPlanner(floor, 1.0, 0.5)))
    for _ in range(14):
        cmd = direct.step(goal)
        other = pyomo.compute(direct.observations[-1])
        assert other.status is cmd.status is ControlStatus.OK
        assert (other.ax, other.ay) == pytest.approx((cmd.ax, cmd.ay), abs=1e-6)
        np.testing.assert_allclose(np.array(other.plan), np.array(cmd.plan), atol=1e-6)
    assert np.hypot(*direct.v) > 0.3  # compared while driving, not just at the start


def test_a_solve_does_not_depend_on_how_long_the_trip_has_been_solving() -> None:
    # A HiGHS object reused for a trip completes a MIP start against its lifetime clock: once
    # the trip's solves added up to the time limit it dropped such a start, so from then on a
    # step searched differently, and when that began depended on the wall clock (fleet runs
    # diverged). The same step, solved until well past the limit, must search alike.
    controller = MPCController(horizon=12, reuse_ticks=0)  # the same trip as when written
    loop = Loop.start(controller, l_hall(zone=True), (2.0, 5.0))
    goal = (18.0, 5.0)
    for _ in range(22):  # past the machine, at a step where the start saves a node
        loop.step(goal)
    model = controller._model
    assert model is not None
    obs = loop.observe(goal)
    assert controller._on_plan(obs)
    data, warm = controller._step_data(obs)
    assert warm is not None
    warm[model._ep_cols] = 0.0  # a start HiGHS has to complete (its tracking errors unset)
    cold = model.solve(data, None)
    model.time_limit_s = 0.25  # some 15 solves of this step
    solutions = [model.solve(data, warm)]
    while sum(s.solver_s for s in solutions) < 2 * model.time_limit_s:
        solutions.append(model.solve(data, warm))
    first = solutions[0]
    assert first.nodes < cold.nodes  # the start matters here: dropping it would show
    for later in solutions:
        assert later.outcome is SolverOutcome.OPTIMAL
        assert later.nodes == first.nodes
        np.testing.assert_array_equal(later.columns, first.columns)


# --- 9. solve reports -----------------------------------------------------------------------------


@pytest.mark.parametrize("interface", ["direct", "pyomo"])
def test_every_command_while_driving_reports_an_optimal_solve(interface: str) -> None:
    goal = (18.0, 5.0)
    # reuse_ticks = 0: every tick solves (a reused plan's command has no report).
    controller = MPCController(horizon=8, interface=interface, reuse_ticks=0)
    loop = Loop.start(controller, L_HALL, (2.0, 5.0), SPEC_1S)
    assert loop.drive(goal, limit=80)
    driving = list(loop.commands)
    for cmd in driving:
        assert cmd.status is ControlStatus.OK
        assert cmd.solve is not None and cmd.solve.outcome is SolverOutcome.OPTIMAL
        assert cmd.solve.solver_s > 0 and cmd.solve.step_s >= cmd.solve.solver_s
    # Parked on the goal the robot holds without a solve, and says it stays for the horizon.
    held = loop.step(goal)
    assert held.status is ControlStatus.OK and held.solve is None
    assert max(abs(held.ax), abs(held.ay)) < 1e-3
    assert held.plan[0][1:] == pytest.approx(held.plan[-1][1:], abs=1e-6)
    assert held.plan[-1][0] > held.plan[0][0]
    assert loop.step(goal).solve is None
    idle = loop.step(None)
    assert idle.status is ControlStatus.IDLE and idle.solve is None


# --- 10. through the engine -----------------------------------------------------------------------


def test_paper_case3_through_the_engine_arrives_safely_and_the_caps_cost_time() -> None:
    runs = {}
    for name in ("paper_case3_s1", "paper_case3_s2"):
        summary = World(load_scenario(ROOT / "scenarios" / f"{name}.toml")).run().summary
        assert summary["controller"] == "mpc"
        assert all(n == 0 for n in summary["violations"].values()), summary["violations"]
        assert summary["solver"]["fallbacks"] == 0
        assert summary["solver"]["steps"] > 0
        # s2's print runs to 251 s, past the paper's 250 s: its robot has arrived and is still
        # printing at the destination, so the job is not delivered yet.
        assert summary["jobs"]["completed"] == (1 if name.endswith("s1") else 0)
        runs[name] = summary["arrivals"]["r01"]
    assert runs["paper_case3_s1"] < 150.0  # the paper's MPC: 160 s
    assert runs["paper_case3_s1"] < runs["paper_case3_s2"] < 250.0  # the paper's: 223 s


# --- the quadratic cost option --------------------------------------------------------------------


def test_the_quadratic_cost_drives_safely_and_more_smoothly_than_the_1_norm() -> None:
    hall = l_hall(zone=True)
    start, goal = (2.0, 5.0), (18.0, 6.0)
    runs = {}
    for cost in ("l1", "quadratic"):
        controller = MPCController(horizon=10, cost=cost)
        loop = Loop.start(controller, hall, start, SPEC_1S)
        # The engine's arrival test (at rest = below 1e-3 m/s): the quadratic cost settles
        # exponentially, never to exactly zero.
        for _ in range(120):
            if math.dist(loop.p, goal) <= ARRIVAL_M and np.max(np.abs(loop.v)) <= 1e-3:
                break
            loop.step(goal)
        else:
            pytest.fail(f"{cost}: at {loop.p} moving {loop.v}")
        assert loop.violations() == []
        assert controller.qp_failures == 0
        inputs = np.array([(c.ax, c.ay) for c in loop.commands])
        runs[cost] = (loop, float(np.sum(inputs**2)))
    # The quadratic cost penalises large inputs more: less input energy over the trip.
    assert runs["quadratic"][1] < runs["l1"][1]
    # Its reports count both solves and keep the MILP's outcome.
    reports = [c.solve for c in runs["quadratic"][0].commands if c.solve is not None]
    assert reports and all(r.outcome is SolverOutcome.OPTIMAL for r in reports)


def test_a_refinement_stopped_by_the_clock_falls_back_and_is_reported_as_a_time_limit() -> None:
    # Whether the QP finished in time depends on the machine, so its step must not use the
    # MILP's plan instead (that would make the run depend on the machine's speed too).
    controller = MPCController(horizon=8, cost="quadratic", reuse_ticks=0)  # every tick solves
    loop = Loop.start(controller, CORRIDOR, (2.0, 2.0), SPEC_HALF)
    for _ in range(4):
        assert loop.step((18.0, 2.0)).status is ControlStatus.OK
    assert controller._model is not None and controller._model.time_limit_s == 10.0
    controller.time_limit_s = 1e-9  # the refinement's guard; the trip's MILP keeps its 10 s

    cmd = loop.step((18.0, 2.0))

    assert cmd.status is ControlStatus.FALLBACK
    assert cmd.solve is not None and cmd.solve.outcome is SolverOutcome.TIME_LIMIT
    assert loop.violations() == []


def test_an_unknown_cost_is_refused() -> None:
    with pytest.raises(ValueError, match="cost = 'l2': must be one of 'l1', 'quadratic'"):
        MPCController(cost="l2")

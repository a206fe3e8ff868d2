"""The path follower on the double integrator: exact tracking, braking, replanning, speed caps."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pytest
import shapely
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from fleet.engine.safety import check_steps
from fleet.errors import PluginError
from fleet.paths import PathPlanner
from fleet.plugins import (
    Command,
    ControllerContext,
    ControlStatus,
    Observation,
    RobotSpec,
    load_controller,
)
from fleet.plugins.testing import CONFORMANCE_SPEC, check_controller, conformance_floor
from fleet_plugins.follower import PathFollower
from fleet_plugins.follower.controller import PLAN_SAMPLE

SPEC = CONFORMANCE_SPEC
DT, A_MAX = SPEC.period, SPEC.a_max
FLOOR = conformance_floor()
PLANNER = PathPlanner(FLOOR, SPEC.v_max, SPEC.a_max)

Goal = tuple[float, float] | None


@dataclass
class Run:
    """A simulated robot: the double integrator, a follower, and everything that happened."""

    controller: PathFollower
    planner: PathPlanner = PLANNER
    spec: RobotSpec = SPEC
    p: np.ndarray = field(default_factory=lambda: np.zeros(2))
    v: np.ndarray = field(default_factory=lambda: np.zeros(2))
    tick: int = 0
    t: list[float] = field(default_factory=list)
    xy: list[np.ndarray] = field(default_factory=list)
    vel: list[np.ndarray] = field(default_factory=list)
    commands: list[Command] = field(default_factory=list)

    @classmethod
    def at(cls, start: tuple[float, float], gain: float = 0.5, **kw: object) -> Run:
        run = cls(PathFollower(gain=gain), **kw)  # type: ignore[arg-type]
        run.p = np.array(start, dtype=float)
        run.controller.reset(ControllerContext("r1", run.spec, FLOOR, run.planner))
        return run

    @property
    def now(self) -> float:
        return self.tick * self.spec.period

    def step(self, goal: Goal, cap: float | None = None, brake_instead: bool = False) -> Command:
        obs = Observation(
            "r1", self.tick, self.now, *map(float, self.p), *map(float, self.v), goal=goal,
            speed_cap=cap,
        )  # fmt: skip
        cmd = self.controller.compute(obs)
        u = np.array([cmd.ax, cmd.ay])
        assert np.all(np.abs(u) <= self.spec.a_max + 1e-12), cmd
        if brake_instead:  # what the engine substitutes when a controller fails
            # Along the line of travel: braking each axis on its own bends the path.
            fastest = np.max(np.abs(self.v))
            u = -self.v / self.spec.period * min(1.0, self.spec.a_max * self.spec.period / fastest)
        self.t.append(self.now)
        self.xy.append(self.p.copy())
        self.vel.append(self.v.copy())
        self.commands.append(cmd)
        self.p = self.p + self.spec.period * self.v
        self.v = self.v + self.spec.period * u
        self.tick += 1
        return cmd

    def until(self, goal: Goal, done: Callable[[Run], bool], limit: int = 2000, **kw) -> None:
        for _ in range(limit):
            if done(self):
                return
            self.step(goal, **kw)
        raise AssertionError(f"not done after {limit} ticks: p={self.p}, v={self.v}")

    def trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Times, positions and velocities including the current state."""
        t = np.array([*self.t, self.now])
        return t, np.array([*self.xy, self.p]), np.array([*self.vel, self.v])


def at_goal(goal: tuple[float, float], tol: float = 1e-6) -> Callable[[Run], bool]:
    return lambda r: np.hypot(*(r.p - goal)) <= tol and np.max(np.abs(r.v)) <= 1e-9


def resting(r: Run) -> bool:
    return bool(np.max(np.abs(r.v)) <= 1e-9) and r.tick > 0


def violations(run: Run) -> list[str]:
    """Every unsafe step, judged by the planner's own step semantics and by fleet.engine.safety."""
    t, xy, v = run.trajectory()
    out = [f"{x.kind} at t={x.t}: {x.detail}" for x in check_steps(FLOOR, t, xy, v, "r1")]
    for k in range(len(xy) - 1):
        if not np.any(v[k]):
            continue
        lim = run.planner.speed_limit(xy[k], xy[k + 1])
        if lim is None:
            out.append(f"step {k} leaves the free space")
        elif abs(v[k, 0]) > lim[0] + 1e-9 or abs(v[k, 1]) > lim[1] + 1e-9:
            out.append(f"step {k}: v={v[k]} over {lim}")
        if not shapely.LineString([xy[k], xy[k + 1]]).within(FLOOR.free_space.buffer(1e-6)):
            out.append(f"step {k} outside free space (shapely)")
    acc = np.abs(np.diff(v, axis=0))
    if np.any(acc > A_MAX * DT + 1e-12):
        out.append(f"acceleration {acc.max() / DT} over {A_MAX}")
    return out


# --- tracking -------------------------------------------------------------------------------------


def test_drives_around_the_press_into_the_slow_zone_reproducing_the_reference() -> None:
    start, goal = (2.0, 5.0), (17.0, 1.5)
    ref = PLANNER.reference(start, goal, dt=DT, t0=0.0)
    run = Run.at(start)
    run.until(goal, at_goal(goal))
    t, xy, v = run.trajectory()

    assert violations(run) == []
    # Arrival (at rest on the goal) comes exactly when the reference ends...
    assert t[-1] == pytest.approx(ref.duration, abs=1e-9)
    # ...because every sample reproduces the reference to rounding.
    np.testing.assert_allclose(xy, ref.positions, rtol=0, atol=1e-9)
    np.testing.assert_allclose(v, ref.velocities, rtol=0, atol=1e-9)
    # The route really tests something: it goes past the press and slows down in the zone.
    in_slow = (xy[:-1, 0] > 14.0 + 1e-6) & (xy[:-1, 1] < 4.0 - 1e-6)
    assert in_slow.sum() > 10
    assert np.max(np.abs(v[:-1][in_slow])) <= 0.4 + 1e-9
    assert np.max(np.abs(v)) > 0.9
    assert all(c.status is ControlStatus.OK for c in run.commands)


def test_the_command_plan_samples_the_next_five_seconds_of_the_reference() -> None:
    start, goal = (2.0, 5.0), (18.0, 7.0)
    ref = PLANNER.reference(start, goal, dt=DT, t0=0.0)
    run = Run.at(start)
    for _ in range(13):
        run.step(goal)
    stride = round(PLAN_SAMPLE / DT)
    # Plans ride on every `stride`-th tick only; the ticks between carry none.
    assert [bool(c.plan) for c in run.commands] == [i % stride == 0 for i in range(13)]
    cmd = run.commands[-1]
    times = np.array([s[0] for s in cmd.plan])
    points = np.array([s[1:] for s in cmd.plan])
    k = 12
    assert times[0] == pytest.approx(run.t[-1])
    assert times[-1] - times[0] == pytest.approx(5.0)
    assert np.allclose(np.diff(times), stride * DT)
    expected = ref.positions[k : k + round(5.0 / DT) + 1 : stride]
    np.testing.assert_allclose(points, expected, atol=1e-12)


def test_holds_at_the_goal_without_drifting() -> None:
    goal = (6.0, 2.0)
    run = Run.at((2.0, 5.0))
    run.until(goal, at_goal(goal))
    arrived = run.p.copy()
    for _ in range(20):
        assert run.step(goal).status is ControlStatus.OK
    assert np.array_equal(run.p, arrived) and not np.any(run.v)


@pytest.mark.parametrize(("gain", "left"), [(0.5, 1e-6), (1.0, 1e-6), (0.0, 2e-4)])
def test_position_feedback_removes_a_small_lead_at_the_rate_set_by_gain(
    gain: float, left: float
) -> None:
    start, goal = (2.0, 5.0), (18.0, 7.0)
    ref = PLANNER.reference(start, goal, dt=DT)
    run = Run.at(start, gain=gain)
    for _ in range(16):
        run.step(goal)
    heading = run.v / np.hypot(*run.v)
    run.p = run.p + 2e-4 * heading  # pushed ahead along its path, less than REPLAN_ERROR
    for _ in range(12):
        run.step(goal)
    error = np.hypot(*(run.p - ref.positions[run.tick]))
    assert error <= left * 1.01 and (gain == 0.0) == (error > 1e-5)


def test_never_faster_than_the_reference_even_when_behind_it() -> None:
    start, goal = (2.0, 5.0), (18.0, 7.0)
    ref = PLANNER.reference(start, goal, dt=DT)
    run = Run.at(start)
    for _ in range(16):
        run.step(goal)
    run.p = run.p - 2e-4 * run.v / np.hypot(*run.v)  # held back along its path
    first = run.tick
    run.until(goal, lambda r: r.tick > ref.steps + 4)
    v = np.array(run.vel[first : ref.steps + 1])
    assert np.all(np.abs(v) <= np.abs(ref.velocities[first:]) + 1e-12)
    assert not np.any(run.vel[ref.steps + 1 :])
    # So it can make up little of the lag, and stops about that much short of the goal, at rest.
    assert 1e-4 < np.hypot(*(run.p - goal)) <= 2e-4 + 1e-12
    assert not np.any(run.v)
    assert violations(run) == []


# --- not on a fresh reference ---------------------------------------------------------------------


def test_no_goal_brakes_along_the_line_of_travel_then_idles_with_zero_acceleration() -> None:
    run = Run.at((2.0, 5.0))
    for _ in range(20):
        run.step((18.0, 7.0))
    heading = run.v / np.hypot(*run.v)
    assert np.hypot(*run.v) > 0.5
    before = len(run.xy)
    run.until(None, resting)
    speeds = np.hypot(*np.array(run.vel[before:]).T)
    assert np.all(np.diff(speeds) < 0)  # strictly slowing down
    for w in run.vel[before:]:
        np.testing.assert_allclose(w / np.hypot(*w), heading, atol=1e-12)  # on a straight line
    assert all(c.status is ControlStatus.IDLE for c in run.commands[before:])
    cmd = run.step(None)
    assert (cmd.ax, cmd.ay, cmd.status) == (0.0, 0.0, ControlStatus.IDLE)
    assert violations(run) == []


def test_a_new_goal_while_moving_brakes_to_rest_then_plans_from_there() -> None:
    first, second = (18.0, 7.0), (2.0, 8.0)
    run = Run.at((2.0, 5.0))
    for _ in range(30):
        run.step(first)
    switched = len(run.xy)
    run.until(second, resting)
    stop_tick, stop = run.tick, run.p.copy()
    ref = PLANNER.reference(tuple(stop), second, dt=DT, t0=run.now)
    run.until(second, at_goal(second))
    assert violations(run) == []
    speeds = np.hypot(*np.array(run.vel[switched:stop_tick]).T)
    assert np.all(np.diff(speeds) < 0)  # nothing but braking before the new plan
    assert run.now == pytest.approx(ref.t_end)  # then the new reference, to the tick


def test_after_the_engine_substituted_braking_it_replans_and_still_arrives_safely() -> None:
    start, goal = (2.0, 5.0), (18.0, 7.0)
    run = Run.at(start)
    for _ in range(25):
        run.step(goal)
    for _ in range(6):  # the agent replaced six commands by braking (e.g. the controller raised)
        run.step(goal, brake_instead=True)
    run.until(goal, at_goal(goal))
    assert violations(run) == []
    ref = PLANNER.reference(start, goal, dt=DT)
    assert run.now > ref.duration  # the disturbance cost time, and was recovered from


def test_an_unreachable_goal_holds_still_with_fallback_and_does_not_replan_every_tick() -> None:
    class Counting(PathPlanner):
        calls = 0

        def reference(self, *args, **kw):  # type: ignore[no-untyped-def]
            type(self).calls += 1
            return super().reference(*args, **kw)

    run = Run.at((2.0, 5.0), planner=Counting(FLOOR, SPEC.v_max, SPEC.a_max))
    for _ in range(10):
        cmd = run.step((10.0, 5.0))  # inside the press
        assert (cmd.ax, cmd.ay, cmd.status) == (0.0, 0.0, ControlStatus.FALLBACK)
    assert Counting.calls == 1
    goal = (3.0, 5.0)
    run.until(goal, at_goal(goal))  # a reachable goal is planned at once
    assert Counting.calls == 2


def test_a_speed_cap_is_respected_from_rest_and_a_zero_cap_holds_the_robot() -> None:
    start, goal = (2.0, 5.0), (18.0, 7.0)
    run = Run.at(start)
    for _ in range(5):
        cmd = run.step(goal, cap=0.0)
        assert (cmd.ax, cmd.ay) == (0.0, 0.0)
    run.until(goal, at_goal(goal), cap=0.3)
    _, _, v = run.trajectory()
    assert np.max(np.abs(v)) <= 0.3 + 1e-9
    assert violations(run) == []
    assert run.now > PLANNER.reference(start, goal, dt=DT).duration + 5.0


def test_a_cap_dropping_mid_trip_brakes_and_continues_under_the_cap() -> None:
    goal = (18.0, 7.0)
    run = Run.at((2.0, 5.0))
    for _ in range(20):
        run.step(goal)
    before = len(run.xy)
    run.until(goal, at_goal(goal), cap=0.3)
    v = np.array(run.vel[before:])
    fast = np.max(np.abs(v), axis=1) > 0.3 + 1e-9
    # Only the first few steps (braking at a_max from at most 1 m/s) may exceed the new cap.
    assert fast.sum() <= round((1.0 - 0.3) / (A_MAX * DT)) + 1
    assert not fast[fast.argmin() :].any()
    assert violations(run) == []


# Stations sit on a millimetre grid, which the planner's start/goal rounding keeps exactly.
MM = st.tuples(st.integers(500, 19500), st.integers(500, 9500)).map(
    lambda p: (p[0] / 1000, p[1] / 1000)
)


@settings(max_examples=12, deadline=None)
@given(MM, MM)
def test_any_trip_on_the_hall_is_safe_and_on_time(
    start: tuple[float, float], goal: tuple[float, float]
) -> None:
    assume(FLOOR.is_free(*start) and FLOOR.is_free(*goal))
    ref = PLANNER.reference(start, goal, dt=DT)
    run = Run.at(start)
    run.until(goal, at_goal(goal, tol=1e-9), limit=ref.steps + 5)
    assert run.now == pytest.approx(ref.duration)
    assert violations(run) == []


def test_a_start_off_the_planners_grid_is_tracked_to_within_its_rounding() -> None:
    # The planner rounds start and goal to 1e-9 m; the follower does not chase that offset
    # (feedback starts at 1e-6 m), so the robot runs parallel to the reference, 2e-10 m away.
    # Here the path runs along the press's west face (the goal is on it).
    start, goal = (8.095666916196702, 1.0), (8.0, 4.0)
    ref = PLANNER.reference(start, goal, dt=DT)
    run = Run.at(start)
    run.until(goal, at_goal(goal, tol=1e-9), limit=ref.steps + 5)
    _, xy, _ = run.trajectory()
    assert np.max(np.abs(xy - ref.positions)) <= 5e-10
    # The planner's own step test forgives it; fleet.engine.safety.check_steps (no distance
    # tolerance) does not, so only the planner's judgement is asserted here.
    for k in range(len(xy) - 1):
        assert run.planner.speed_limit(xy[k], xy[k + 1]) is not None


# --- options and the contract ---------------------------------------------------------------------


@pytest.mark.parametrize("gain", [-0.1, 1.5, float("nan"), "0.5", True])
def test_gain_outside_zero_to_one_is_refused_with_the_bad_value(gain: object) -> None:
    with pytest.raises(ValueError, match=r"gain = .*\[0, 1\]"):
        PathFollower(gain=gain)  # type: ignore[arg-type]
    with pytest.raises(PluginError, match=r"'follower'.*gain"):
        load_controller("follower", {"gain": gain})


@pytest.mark.parametrize("gain", [0.0, 0.5, 1.0])
def test_the_follower_passes_the_conformance_check(gain: float) -> None:
    check_controller(PathFollower, options={"gain": gain})


def test_is_registered_as_follower() -> None:
    follower = load_controller("follower")
    assert isinstance(follower, PathFollower) and follower.gain == 0.5


def test_a_tracking_command_after_which_braking_would_leave_the_floor_is_held_back() -> None:
    """Braking is the follower's answer to everything, so each tracking command is sent only if
    braking after it stays in the free space (issue 16: a brake ran 3 cm into a wall)."""
    from fleet.plugins import Command
    from fleet_plugins.follower.guard import Guard

    guard = Guard(SPEC, FLOOR, margin_m=0.1, yield_s=2.0, hold_steps=8)

    def brakes_inside(obs: Observation) -> bool:  # after a command that keeps the speed
        return guard.stops_inside(
            obs, guard.braking_after(obs, Command(0.0, 0.0, ControlStatus.OK))
        )

    x0, _, x1, _ = FLOOR.free_space.bounds
    # 0.5 m short of the wall at x = 20, at 1 m/s towards it: a stop takes 1 m.
    towards = Observation("r1", 0, 0.0, x1 - 0.5, 5.0, 1.0, 0.0, goal=(x1 - 0.1, 5.0))
    assert not brakes_inside(towards)
    # The same speed along the wall, or 2 m short: braking stays on the floor.
    along = Observation("r1", 0, 0.0, x1 - 0.5, 5.0, 0.0, 1.0, goal=(x1 - 0.5, 8.0))
    assert brakes_inside(along)
    far = Observation("r1", 0, 0.0, x1 - 2.0, 5.0, 1.0, 0.0, goal=(x1 - 0.1, 5.0))
    assert brakes_inside(far)
    # At rest nothing can go wrong.
    rest = Observation("r1", 0, 0.0, x0 + 0.01, 5.0, 0.0, 0.0, goal=(5.0, 5.0))
    assert brakes_inside(rest)

"""The MPC among other robots: separation constraints against their plans, with real HiGHS.

Controller-level tests drive one MPC by hand (as tests/test_mpc.py does) past another robot
whose plan is given: the other robot moves exactly along its plan, and every distance below is
measured between the two simulated robots (or between the MPC's plan and the other's), never
taken from the controller's word. The last tests run two MPC robots through the engine.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import box

from fleet.engine import World
from fleet.floor import Floor, FloorSpec
from fleet.paths import PathPlanner
from fleet.plugins import (
    Command,
    ControllerContext,
    ControlStatus,
    Neighbour,
    Observation,
    RobotSpec,
    SolverOutcome,
)
from fleet.plugins.robot import DoubleIntegrator, brake_input
from fleet.scenario import parse_scenario
from fleet_plugins.mpc import MPCController
from fleet_plugins.mpc.neighbours import closest_approach
from fleet_plugins.mpc.separation import ACROSS, Obstacle, build_separation, predict, spans

SPEC = RobotSpec(v_max=1.0, a_max=0.5, radius=0.4, period=0.5)
CONTACT = 0.8  # the two robots' radii: closer than this is a collision
HALL = Floor.from_regions(
    FloorSpec(
        source="<test hall>",
        name="hall",
        boundary=box(0, 0, 20, 10),
        default_v_max=(1.0, 1.0),
    ),
    [(box(0, 0, 20, 10), (1.0, 1.0), None)],
)
START, GOAL = (2.0, 5.0), (18.0, 5.0)

Path2 = Callable[[float], tuple[float, float]]


def solving_mpc(**options: object) -> MPCController:
    """An MPC that solves every tick (``reuse_ticks = 0``): these tests judge each solve."""
    return MPCController(**{"reuse_ticks": 0, **options})  # type: ignore[arg-type]


def crossing(t: float) -> tuple[float, float]:
    """A robot driving north across the hall at x = 10, at the centre line at t = 10 s, which is
    where and when the MPC robot gets there driving east along y = 5."""
    return (10.0, 5.0 + 0.8 * (t - 10.0))


def parked(t: float) -> tuple[float, float]:
    """A robot standing on the MPC robot's straight line."""
    return (10.0, 5.0)


def far_away(t: float) -> tuple[float, float]:
    """A robot shuttling along the far wall, out of reach of an 8-step (4 s) plan: in 4 s the
    MPC robot gets at most 3 m off its line y = 5, and the squares are 0.9 m wide."""
    return (10.0 + 8.0 * math.sin(t / 4), 9.6)


def neighbour(
    path: Path2, t: float, steps: int, *, priority: int = 1, with_plan: bool = True
) -> Neighbour:
    """The robot on `path` as the engine lists it at `t`, with its plan for `steps` periods."""
    dt = SPEC.period
    x, y = path(t)
    x1, y1 = path(t + dt)
    plan = tuple((t + k * dt, *path(t + k * dt)) for k in range(steps + 1)) if with_plan else ()
    return Neighbour("r2", x, y, (x1 - x) / dt, (y1 - y) / dt, 0.4, priority, plan)


class Run:
    """One MPC robot ("r1", priority 0) on `HALL` next to one other robot on a known path."""

    def __init__(self, controller: MPCController, other: Path2 | None, **kw: object) -> None:
        self.controller = controller
        controller.reset(ControllerContext("r1", SPEC, HALL, PathPlanner(HALL, 1.0, 0.5)))
        self.other, self.kw = other, kw
        self.p, self.v = np.array(START), np.zeros(2)
        self.robot = DoubleIntegrator(SPEC.period, SPEC.a_max)
        self.t = 0.0
        self.commands: list[Command] = []
        self.gaps: list[float] = []  # distance between the two robots after each step

    def step(
        self, goal: tuple[float, float] = GOAL, shadow: MPCController | None = None
    ) -> Command:
        """One tick; a `shadow` controller is asked on the same observation (not followed)."""
        near = ()
        if self.other is not None:
            near = (neighbour(self.other, self.t, self.controller.horizon, **self.kw),)  # type: ignore[arg-type]
        obs = Observation(
            "r1", len(self.commands), self.t, *map(float, self.p), *map(float, self.v),
            goal=goal, neighbours=near,
        )  # fmt: skip
        cmd = self.controller.compute(obs)
        if shadow is not None:
            shadow.compute(obs)
        self.commands.append(cmd)
        x, y, vx, vy = self.robot.step(*self.p, *self.v, cmd.ax, cmd.ay)
        self.p, self.v = np.array([x, y]), np.array([vx, vy])
        self.t += SPEC.period
        if self.other is not None:
            self.gaps.append(math.dist(self.p, self.other(self.t)))
        return cmd

    def drive(self, ticks: int) -> bool:
        """Step until at rest on the goal (True) or `ticks` steps (False)."""
        for _ in range(ticks):
            if math.dist(self.p, GOAL) <= 0.05 and np.max(np.abs(self.v)) <= 1e-9:
                return True
            self.step()
        return False


# --- plans keep clear -----------------------------------------------------------------------------


@pytest.mark.parametrize("other", [crossing, parked], ids=["crossing", "parked"])
def test_the_plan_keeps_the_radii_apart_from_the_other_robot_at_every_step(other: Path2) -> None:
    run = Run(solving_mpc(horizon=12), other)
    assert run.drive(80)
    for cmd in run.commands:
        assert cmd.status is ControlStatus.OK
        plan = np.array(cmd.plan)
        there = np.array([other(t) for t in plan[:, 0]])
        # Outside the square of half-width r_i + r_j (its hard part) at every step, so the
        # discs never touch; and never inside the margin unless it had to be (it never had to).
        sep = np.max(np.abs(plan[1:, 1:] - there[1:]), axis=1)
        assert np.all(sep >= CONTACT + 0.1 - 1e-6), sep.min()
    constrained = sum(b > 0 for b in run.controller.separation_binaries)
    assert constrained >= 5  # the other robot really was in the way for a while
    assert min(run.gaps) >= CONTACT + 0.1 - 1e-6  # and the simulated robots kept apart


def test_without_separation_the_same_robot_runs_into_the_crossing_one() -> None:
    run = Run(solving_mpc(horizon=12, avoid_robots=False), crossing)
    assert run.drive(80)
    assert min(run.gaps) < CONTACT  # so the test above can fail
    assert set(run.controller.separation_binaries) == {0}


def test_a_robot_out_of_reach_adds_no_binaries_and_changes_nothing() -> None:
    alone = Run(solving_mpc(horizon=8), None)
    beside = Run(solving_mpc(horizon=8), far_away)
    for _ in range(24):
        a, b = alone.step(), beside.step()
        assert (a.ax, a.ay, a.status) == (b.ax, b.ay, b.status)
        np.testing.assert_array_equal(np.array(a.plan), np.array(b.plan))
    assert beside.controller.separation_binaries == [0] * 24
    assert beside.controller.separation_robots == [()] * 24
    assert np.hypot(*beside.v) > 0.5  # compared while driving


def test_a_robot_with_no_plan_is_taken_to_stay_where_it_is() -> None:
    run = Run(solving_mpc(horizon=12), parked, with_plan=False)
    assert run.drive(80)
    assert min(run.gaps) >= CONTACT + 0.1 - 1e-6
    assert max(len(r) for r in run.controller.separation_robots) == 1


# --- priorities -----------------------------------------------------------------------------------


def test_a_higher_priority_robot_keeps_its_course_unless_the_lower_one_is_parked_or_close() -> None:
    # r1 has priority 0; here the other robot has -1, so r1 goes first.
    ahead = Run(solving_mpc(horizon=12), crossing, priority=-1)
    respect_none = Run(solving_mpc(horizon=12, respect_priority=False), crossing, priority=-1)
    for _ in range(12):  # until the other robot is still 3 m from r1's line at t = 6 s
        ahead.step()
        respect_none.step()
    assert set(ahead.controller.separation_robots) == {()}  # moving and far: it yields to r1
    assert ("r2",) in respect_none.controller.separation_robots
    # Parked lower-priority robots are avoided all the same.
    run = Run(solving_mpc(horizon=12), parked, priority=-1)
    assert run.drive(80)
    assert min(run.gaps) >= CONTACT + 0.1 - 1e-6


def test_equal_priorities_are_ordered_by_robot_id() -> None:
    run = Run(solving_mpc(horizon=12), crossing, priority=0)  # "r1" < "r2": r1 goes first
    for _ in range(12):
        run.step()
    assert set(run.controller.separation_robots) == {()}


# --- the fallback ---------------------------------------------------------------------------------


def test_a_fallback_brakes_rather_than_follow_its_old_plan_into_another_robot() -> None:
    controller = solving_mpc(horizon=8, warm_start=False)
    run = Run(controller, None)
    for _ in range(8):
        run.step()
    plan = np.array(run.commands[-1].plan)
    assert np.hypot(*run.v) > 0.5
    # The solver fails from now on, and a robot turns up on the old plan's last point.
    controller.time_limit_s = 1e-6
    assert controller._model is not None
    controller._model.time_limit_s = 1e-6
    end = (float(plan[-1, 1]), float(plan[-1, 2]))
    run.other = lambda t: end
    here, (vx, vy) = run.p.copy(), map(float, run.v)
    cmd = run.step()
    assert cmd.status is ControlStatus.FALLBACK
    assert cmd.solve is not None and cmd.solve.outcome is SolverOutcome.TIME_LIMIT
    assert (cmd.ax, cmd.ay) == brake_input(vx, vy, SPEC.period, SPEC.a_max)
    # Its plan is the braking path (for the other robots to avoid), ending at rest short of it.
    brake = np.array(cmd.plan)
    np.testing.assert_allclose(brake[0, 1:], here)
    np.testing.assert_allclose(brake[1, 1:], run.p)
    assert math.dist(brake[-1, 1:], end) > CONTACT


def test_with_no_robot_on_it_the_fallback_still_follows_the_old_plan() -> None:
    controller = solving_mpc(horizon=8, warm_start=False)
    run = Run(controller, far_away)
    for _ in range(8):
        run.step()
    controller.time_limit_s = 1e-6
    assert controller._model is not None
    controller._model.time_limit_s = 1e-6
    expected = run.commands[-1].plan[2]  # the old plan's next sample
    cmd = run.step()
    assert cmd.status is ControlStatus.FALLBACK
    assert cmd.plan[1] == pytest.approx(expected)


# --- the rows themselves --------------------------------------------------------------------------


def test_a_robot_already_too_close_makes_its_square_soft_not_the_problem_infeasible() -> None:
    n = 6
    p_lo = np.array([[5.0, 5.0]] * 2 + [[3.0, 3.0]] * (n - 1))
    p_hi = np.array([[5.0, 5.0]] * 2 + [[7.0, 7.0]] * (n - 1))
    centres = np.tile([5.5, 5.0], (n + 1, 1))  # 0.5 m away at the fixed p[1]: inside 0.8
    sep = build_separation([Obstacle.square("r2", centres, 0.9, 0.1)], p_lo, p_hi)
    assert not sep.infeasible
    assert np.all(sep.group_slack == pytest.approx(0.9))
    further = np.tile([7.5, 5.0], (n + 1, 1))  # 2.5 m away: the usual margin
    sep = build_separation([Obstacle.square("r2", further, 0.9, 0.1)], p_lo, p_hi)
    assert sep.groups > 0 and np.all(sep.group_slack == pytest.approx(0.1))


def test_a_robot_inside_the_square_but_not_in_contact_gets_a_side_across_not_a_soft_square():
    # 80 MPC robots on the fleet scenario (t = 100 s): r22's next position was 0.40 m along x
    # and 0.696 m along y from r46 at rest, 0.8025 m apart (radii 0.4): inside the square, out
    # of contact. The whole square went soft and r22's plan came to 0.7985 m (contact).
    n = 6
    here = np.array([10.40, 4.304])
    p_lo = np.vstack([[here] * 2, [[8.0, 3.0]] * (n - 1)])
    p_hi = np.vstack([[here] * 2, [[12.0, 7.0]] * (n - 1)])
    other = np.tile([10.0, 5.0], (n + 1, 1))
    sep = build_separation([Obstacle.square("r2", other, 0.9, 0.1)], p_lo, p_hi)
    assert not sep.infeasible
    assert np.all(sep.group_slack == pytest.approx(0.1))  # only the margin is soft
    np.testing.assert_allclose(sep.normals[0], (here - other[0]) / np.linalg.norm(here - other[0]))
    assert ACROSS in sep.binary_side
    # A plan point in contact breaks the side across; one 0.8 m along the normal keeps it.
    k = int(sep.group_last[0])
    assert sep._clearance(0, ACROSS, k, np.array([10.2, 4.5])) + 0.1 < 0
    assert sep._clearance(0, ACROSS, k, other[k] + 0.8 * sep.normals[0]) + 0.1 == pytest.approx(0)


@pytest.mark.parametrize(("vx", "vy", "dy"), [(-0.6, 0.0, 0.696), (-0.5, 0.2, 0.75)])
def test_a_plan_from_inside_the_square_keeps_out_of_contact(vx, vy, dy) -> None:
    # r1 heads west under r2, parked at (10, 5): its next position is 0.4 m east and `dy`
    # south of r2, inside the square but out of contact, and its goal lies west on that line.
    # With the whole square soft, plans came to 0.798 and 0.789 m, and r1 to 0.789 m (contact).
    run = Run(solving_mpc(horizon=12), parked, priority=5)
    dt = SPEC.period
    run.p, run.v = np.array([10.4 - vx * dt, 5.0 - dy - vy * dt]), np.array([vx, vy])
    for _ in range(6):
        cmd = run.step(goal=(2.0, 5.0 - dy))
        assert cmd.status is ControlStatus.OK
        plan = np.array([s[1:] for s in cmd.plan])
        assert closest_approach(plan, np.tile([10.0, 5.0], (len(plan), 1))) >= CONTACT - 1e-6
    assert min(run.gaps) >= CONTACT - 1e-6


def test_when_the_side_across_is_too_strict_the_square_is_soft_and_the_plan_steers_away():
    # Faster (1 m/s west) from 0.7 m south: every plan keeping to one side across would come
    # closer along it on the next step, so the solve is infeasible; braking straight on would
    # pass 0.7 m under r2. The soft square gets a plan that steers away, out of contact.
    run = Run(solving_mpc(horizon=12), parked, priority=5)
    run.p, run.v = np.array([10.4 + 1.0 * SPEC.period, 4.3]), np.array([-1.0, 0.0])
    for _ in range(6):
        assert run.step(goal=(2.0, 4.3)).status is ControlStatus.OK
    assert min(run.gaps) >= CONTACT - 1e-6


def test_prediction_interpolates_the_plan_and_holds_its_last_sample() -> None:
    n = Neighbour("r2", 0.0, 0.0, 1.0, 0.0, plan=((0.5, 0.5, 0.0), (1.5, 1.5, 1.0)))
    got = predict(n, 0.0, 0.5, 5)
    expected = [[0, 0], [0.5, 0], [1.0, 0.5], [1.5, 1.0], [1.5, 1.0], [1.5, 1.0]]
    np.testing.assert_allclose(got, expected)
    np.testing.assert_allclose(
        predict(Neighbour("r2", 3.0, 4.0, 1.0, 0.0), 0.0, 0.5, 2), [[3, 4]] * 3
    )


def test_groups_cover_the_horizon_and_share_their_ends() -> None:
    for n, dt in ((25, 1.0), (24, 0.25), (16, 0.5), (2, 1.0)):
        groups = spans(n, dt)
        assert groups[0][0] == 1 and groups[-1][1] == n
        assert all(a[1] == b[0] for a, b in zip(groups[:-1], groups[1:], strict=True))


@pytest.mark.parametrize(
    ("option", "value", "rule"),
    [
        ("avoid_robots", 1, "must be a bool"),
        ("respect_priority", "yes", "must be a bool"),
        ("separation_margin_m", -0.1, "must be a number >= 0"),
        ("max_neighbours", 1.5, "must be an integer >= 0"),
    ],
)
def test_bad_fleet_options_are_refused(option: str, value: object, rule: str) -> None:
    with pytest.raises(ValueError, match=f"option {option} = {value!r}: {rule}"):
        MPCController(**{option: value})  # type: ignore[arg-type]


# --- other model paths ----------------------------------------------------------------------------


def test_the_pyomo_interface_and_the_quadratic_cost_keep_clear_too() -> None:
    # Both interfaces solve the same MILP on every observation: the same optimal cost (their
    # plans may differ where the cost has several optima) and both keep clear.
    direct = Run(solving_mpc(horizon=12), crossing)
    shadow = solving_mpc(horizon=12, interface="pyomo")
    shadow.reset(ControllerContext("r1", SPEC, HALL, PathPlanner(HALL, 1.0, 0.5)))
    pyomo = Run(solving_mpc(horizon=12, interface="pyomo"), crossing)
    for _ in range(24):
        direct.step(shadow=shadow)
        pyomo.step()
        a, b = direct.controller._last, shadow._last
        assert a is not None and b is not None and a.objective is not None
        assert b.objective == pytest.approx(a.objective, rel=1e-7, abs=1e-6)
    assert max(direct.controller.separation_binaries) > 0
    assert max(shadow.separation_binaries) > 0
    assert min(pyomo.gaps) >= CONTACT + 0.1 - 1e-6
    quadratic = Run(solving_mpc(horizon=12, cost="quadratic"), crossing)
    assert quadratic.drive(80)
    assert quadratic.controller.qp_failures == 0
    # Every solved plan keeps clear (a robot parked on its goal holds without a solve).
    for cmd in (c for c in quadratic.commands if c.solve is not None):
        plan = np.array(cmd.plan)
        there = np.array([crossing(t) for t in plan[:, 0]])
        assert np.all(np.max(np.abs(plan[1:, 1:] - there[1:]), axis=1) >= CONTACT - 1e-6)
    assert min(quadratic.gaps) >= CONTACT


# --- through the engine ---------------------------------------------------------------------------

CORRIDOR_MAP = """
[floor]
name = "corridor"
rect = [0, 0, 20, 6]
default_v_max = 1.0
clearance = 0.4

[[stations]]
name = "west"
at = [1.5, 3]

[[stations]]
name = "east"
at = [18.5, 3]
"""


def head_on(tmp_path: Path, **options: object) -> dict:
    """Two MPC robots swap ends of a corridor (each job goes via the other end and back)."""
    (tmp_path / "corridor.toml").write_text(CORRIDOR_MAP)
    raw = {
        "scenario": {"map": "corridor.toml", "duration_s": 45, "sensing_radius_m": 10},
        "robots": {
            "count": 2,
            "start": ["west", "east"],
            "period_s": 0.5,
            "return_home": False,
        },
        "controller": {"name": "mpc", "options": {"horizon": 12, **options}},
        "jobs": {
            "mode": "scripted",
            "scripted": [
                {"at_s": 0, "station": "west", "via": ["east"]},
                {"at_s": 0, "station": "east", "via": ["west"]},
            ],
        },
    }
    return World(parse_scenario(raw, tmp_path / "head_on.toml")).run().summary


def test_two_mpc_robots_head_on_pass_each_other_without_contact(tmp_path: Path) -> None:
    summary = head_on(tmp_path)
    assert summary["violations"]["collision"] == 0
    assert summary["jobs"]["completed"] == 2  # both went past each other and back
    assert summary["solver"]["fallbacks"] == 0


def test_two_mpc_robots_that_ignore_each_other_collide_head_on(tmp_path: Path) -> None:
    assert head_on(tmp_path, avoid_robots=False)["violations"]["collision"] > 0

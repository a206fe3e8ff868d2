"""When a solve fails (plugins/mpc/recover.py): the previous plan stays in the free space, a
braking path need not, and a neighbour's prediction does not make the robot leave it; a brake
keeps clear of a robot at rest where one of the brakes can, after a failed solve or with no
solve at all (two tests with their own state); a plan solved before a print began is followed
only within the print's caps (the last test, on this floor).

Fuzz floor s91-0042 (2 MPC robots, with the settling rule of `neighbours`): r01 had just passed
station st1 and drove south along the slanted west face of obstacle m00_irregular, its plan
turning west along that face; r02 (the higher robot) bound for st1 planned across r01's path.
r01's solves went infeasible; its previous plan, one step on, was judged not clear of r02's
plan, so it braked straight on, although no braking path stayed in the free space there (its
braking path came no farther from r02 than the plan): 3.7 mm into the obstacle's clearance,
208 obstacle steps by the engine's checker, 214 fallbacks. The states below are that run's, at
the ticks 67.0, 67.25 and 67.5 s, with r02's published plan, on that case's floor.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString

from fleet.engine import World
from fleet.floor import BOUNDARY_BAND, Floor, load_floor
from fleet.paths import PathPlanner
from fleet.plugins import (
    ControllerContext,
    ControlStatus,
    Neighbour,
    Observation,
    RobotSpec,
    SolveReport,
    SolverOutcome,
)
from fleet.scenario import REPO_ROOT, load_scenario
from fleet_plugins.mpc.controller import MPCController
from fleet_plugins.mpc.fallback import brake, free_brake
from fleet_plugins.mpc.neighbours import clear_of_neighbours, closest_approach
from fleet_plugins.mpc.recover import fall_back

SPEC = RobotSpec(v_max=1.42, a_max=0.34, radius=0.423, period=0.25)
#: The case's map file, whole (the controller's regions and reference depend on all of it).
FLOOR_TOML = """
[floor]
name = "fuzz floor 91-42"
description = "22.23 x 15.61 m hall rotated 0.0 deg"
default_v_max = 1.12
clearance = 0.423
rect = [-11.3, 15.13, 10.93, 30.74]

[[obstacles]]
name = "m00_irregular"
polygon = [
    [-4.1032, 28.0176], [-5.2534, 27.7534], [-5.7375, 26.3132], [-5.427, 26.387],
    [-5.0213, 25.8928], [-3.6501, 25.9405], [-3.3519, 26.8742],
]

[[obstacles]]
name = "m01_L"
polygon = [
    [-1.089, 22.7921], [-0.2473, 22.7921], [-0.2473, 23.5199], [-0.3612, 23.5199],
    [-0.3612, 24.141], [-1.089, 24.141],
]

[[obstacles]]
name = "m02_irregular"
polygon = [
    [-8.5698, 27.0638], [-8.2565, 26.9402], [-7.9332, 27.4301], [-7.7927, 28.162],
    [-8.7146, 28.3554],
]

[[obstacles]]
name = "m03_irregular"
polygon = [
    [6.4608, 24.3446], [5.9845, 24.3494], [4.6926, 24.7261], [4.4487, 24.3476],
    [4.8895, 22.1881], [5.9568, 21.3057], [5.9602, 22.2209],
]

[[obstacles]]
name = "m04_triangle"
polygon = [[-6.6875, 18.5777], [-6.1042, 20.5055], [-8.8347, 19.3383]]

[[obstacles]]
name = "m05_L"
polygon = [
    [6.5261, 23.5675], [8.2078, 23.5675], [8.2078, 24.0024], [6.961, 24.0024],
    [6.961, 24.6989], [6.5261, 24.6989],
]

[[obstacles]]
name = "m06_irregular"
polygon = [
    [0.7381, 27.1576], [0.6573, 27.5927], [0.5817, 27.217], [-0.9495, 25.5171],
    [0.8094, 24.2234], [2.1102, 26.2529],
]

[[obstacles]]
name = "gap_a"
polygon = [[5.8747, 30.685], [4.2619, 29.7229], [5.9113, 26.9578], [7.5241, 27.9198]]

[[obstacles]]
name = "gap_b"
polygon = [[3.308, 29.154], [1.6952, 28.1919], [3.3446, 25.4268], [4.9574, 26.3888]]

[[zones]]
name = "z0"
polygon = [[-2.9481, 26.243], [-3.369, 18.2742], [-11.29, 18.6926], [-11.29, 26.6836]]
v_max = 0.76

[[zones]]
name = "m05_L_buf"
around = "m05_L"
margin = 0.66
v_max = 0.28

[[zones]]
name = "m05_L_ring"
around = "m05_L_buf"
margin = 1.96
v_max = 0.49

[[stations]]
name = "st0"
at = [8.3911, 18.7292]
kind = "depot"

[[stations]]
name = "st1"
at = [-5.743, 27.6871]
kind = "delivery"

[[stations]]
name = "st2"
at = [-0.4121, 19.4911]
kind = "delivery"
"""


@pytest.fixture(scope="module")
def floor(tmp_path_factory: pytest.TempPathFactory) -> Floor:
    """The case's floor, loaded from its map file."""
    path = tmp_path_factory.mktemp("s91-0042") / "floor.toml"
    path.write_text(FLOOR_TOML)
    return load_floor(path, cache=False)


ST2 = (-0.4121, 19.4911)  # r01's goal


def r02(
    x: float, y: float, vx: float, vy: float, plan: list[tuple[float, float, float]]
) -> Neighbour:
    """r02 as r01 saw it (priority 7, above r01's 4)."""
    return Neighbour(
        "r02", x, y, vx, vy, 0.423, 7, tuple(plan), v_max=1.42, a_max=0.34, period=0.25
    )


def r01(tick: int, t: float, x: float, y: float, vx: float, vy: float, n: Neighbour) -> Observation:
    """r01's observation at one tick, bound for st2 with job j00002, `n` in sight."""
    return Observation(
        "r01", tick, t, x, y, vx, vy, goal=ST2, job="j00002", neighbours=(n,), priority=4
    )


TICKS = [
    r01(268, 67.0, -5.841478477267816, 27.475997583324297, -0.10712753495743144,
        -0.38110241655072236,
        r02(-7.001110078874998, 27.96505006683657, 0.33999995749999895, -0.045069034497613875,
            [(67.0, -7.011735078874998, 27.966458474340673),
             (67.25, -6.916110089499998, 27.953782808212168),
             (67.75, -6.809860110749999, 27.939698735987967),
             (68.0, -6.788610121374999, 27.93688192238817)])),
    r01(269, 67.25, -5.868260361007174, 27.380721979186617, -0.02212753495743143,
        -0.29610241655072234,
        r02(-6.916110089499998, 27.953782808212168, 0.25499995749999893, -0.03380177446480287,
            [(67.25, -6.926735089499998, 27.95519121571627),
             (67.5, -6.852360100124999, 27.945332364595966),
             (68.0, -6.788610121374999, 27.93688192238817)])),
    r01(270, 67.5, -5.873792244746531, 27.306696375048936, -0.008707428759131088,
        -0.21110241655072232,
        r02(-6.852360100124999, 27.945332364595966, 0.33999995749999895, -0.11503210866529656,
            [(67.5, -6.841735100124999, 27.935178572820902),
             (67.75, -6.767360110749999, 27.91657433742964),
             (68.25, -6.5436901075312495, 27.85905828309699),
             (68.75, -6.308850079843749, 27.80154222876434),
             (69.25, -6.074010052156249, 27.744026174431696),
             (69.75, -5.878673368104165, 27.701184073632685),
             (70.25, -5.768336684052082, 27.6871), (70.75, -5.743, 27.6871),
             (73.5, -5.743, 27.6871)])),
]  # fmt: skip


def in_free_space(floor: Floor, points: list[tuple[float, float]]) -> bool:
    """Whether the robot's centre stays in the `floor`'s free space along the straight steps
    (within the band the engine's checker allows)."""
    free = floor.free_space.buffer(BOUNDARY_BAND, join_style="mitre")
    return bool(shapely.covers(free, LineString(points)))


def test_a_failed_solve_next_to_a_wall_keeps_the_plan_rather_than_brake_into_the_wall(
    floor: Floor,
) -> None:
    c = MPCController()
    c.reset(ControllerContext("r01", SPEC, floor, PathPlanner(floor, v_max=1.42, a_max=0.34)))
    before, after = c.compute(TICKS[0]), c.compute(TICKS[1])
    # The run's two solves: the second plan turns west along the obstacle's face.
    assert before.status is after.status is ControlStatus.OK
    assert after.solve is not None and after.solve.outcome.usable
    shown = [(x, y) for _, x, y in after.plan]
    assert in_free_space(floor, shown)
    obs = TICKS[2]
    # One step on, every brake leaves the free space, and the plan runs close to r02's.
    assert free_brake(obs, SPEC, floor) is None
    assert not clear_of_neighbours(obs, SPEC, np.array(shown[1:] + shown[-1:]))
    cmd = c.compute(obs)
    assert cmd.status is ControlStatus.FALLBACK
    assert cmd.solve is not None and not cmd.solve.outcome.usable  # the solve failed
    # Before: braking straight on, whose path ran 3.7 mm into m00_irregular's clearance.
    path = [(x, y) for _, x, y in cmd.plan]
    assert path[0] == (obs.x, obs.y)
    assert in_free_space(floor, path)
    assert path[1:] == shown[2:] + shown[-1:] * (len(path) - len(shown) + 1)  # the plan, on


#: 80 MPC robots on the fleet scenario (bench_fleet.py --sweep 80 --duration 600
#: --release-until 120 --seed 2, on a commit since reverted), t = 175.5 s: r40, 0.89 m from r34
#: at rest. The state as the engine made it.
R40_SPEC = RobotSpec(v_max=1.0, a_max=0.5, radius=0.4, period=0.25)
R34 = Neighbour("r34", 76.40367752684367, 13.356769812649526, 0.0, 0.0, 0.4, 127,
                ((175.5, 76.40367752684367, 13.356769812649526),
                 (181.5, 76.40367752684367, 13.356769812649526)))  # fmt: skip
R40 = Observation("r40", 702, 175.5, 76.30812428450983, 14.245311899054474,
                  0.4688994374039339, -0.1985400568319129, goal=(78.0, 48.0),
                  neighbours=(R34,), priority=41)  # fmt: skip


def gap_to_r34(plan: tuple[tuple[float, float, float], ...]) -> float:
    p = np.array([q[1:] for q in plan])
    return closest_approach(p, np.tile([R34.x, R34.y], (len(p), 1)))


@pytest.fixture(scope="module")
def fleet_floor() -> Floor:
    return World(load_scenario(REPO_ROOT / "scenarios" / "fleet.toml")).floor


def test_a_fallback_brake_keeps_clear_of_a_robot_at_rest_where_a_brake_can(
    fleet_floor: Floor,
) -> None:
    # r40's solve is infeasible. Braking along its line of travel brought it to 0.7915 m of r34
    # (radii 0.4): a contact. Braking both axes at the full rate keeps clear, and a fallback
    # now takes it. The real floor.
    obs, spec, floor = R40, R40_SPEC, fleet_floor
    report = SolveReport(SolverOutcome.INFEASIBLE, 0.003, 0.009)
    straight = brake(obs, spec, 25, ControlStatus.FALLBACK, floor)
    assert gap_to_r34(straight.plan) < 0.8  # the brake it took: into r34
    cmd, kept = fall_back(obs, spec, 25, floor, None, False, True, report)
    assert cmd.status is ControlStatus.FALLBACK and cmd.solve is report and kept is None
    assert gap_to_r34(cmd.plan) >= 0.8
    # It is a brake: each axis slows, none speeds up or turns round.
    vx, vy = obs.vx + spec.period * cmd.ax, obs.vy + spec.period * cmd.ay
    assert 0.0 <= vx < obs.vx and obs.vy < vy <= 0.0
    # Without robots to avoid (`avoid_robots` off) the fallback brakes as before.
    cmd, _ = fall_back(obs, spec, 25, floor, None, False, False, report)
    assert cmd.plan == straight.plan


@pytest.mark.parametrize("avoid_robots", [True, False])
def test_a_robot_stopping_without_a_solve_brakes_clear_of_a_robot_at_rest_too(
    fleet_floor: Floor, avoid_robots: bool
) -> None:
    # The same state with r40's goal withdrawn (its job handed back: IDLE, `recover.stop`).
    # Its brake ran straight on into r34 as the failed solve's did; now it takes the same
    # clear brake, unless the controller ignores other robots.
    c = MPCController(avoid_robots=avoid_robots)
    c.reset(ControllerContext("r40", R40_SPEC, fleet_floor, PathPlanner(fleet_floor, 1.0, 0.5)))
    cmd = c.compute(replace(R40, goal=None))
    assert cmd.status is ControlStatus.IDLE
    straight = brake(R40, R40_SPEC, c.horizon, ControlStatus.IDLE, fleet_floor)
    if avoid_robots:
        assert gap_to_r34(cmd.plan) >= 0.8 > gap_to_r34(straight.plan)
        vx, vy = R40.vx + R40_SPEC.period * cmd.ax, R40.vy + R40_SPEC.period * cmd.ay
        assert 0.0 <= vx < R40.vx and R40.vy < vy <= 0.0  # a brake
    else:
        assert cmd.plan == straight.plan


ST0 = (8.3911, 18.7292)  # a depot on the s91-0042 floor, east across the open south of it


@pytest.mark.parametrize("cap", [0.2, 1.5])
def test_a_failed_solve_as_a_print_starts_brakes_rather_than_follow_a_plan_over_its_cap(
    floor: Floor, cap: float
) -> None:
    # Fuzz s97-0728: r08, driving off at 0.26 m/s, was given a job at the station it was
    # leaving; the print's 0.28 m/s cap ran from the next step and its solves were infeasible
    # (a neighbour). Its fallback followed its plan home, solved before the print existed, to
    # 1.18 m/s. Here: a real plan from rest, then a failed solve one tick on, on that plan,
    # with a print whose cap runs from the next step.
    c = MPCController()
    c.reset(ControllerContext("r08", SPEC, floor, PathPlanner(floor, v_max=1.42, a_max=0.34)))
    assert c.compute(Observation("r08", 0, 0.0, -8.0, 16.5, 0.0, 0.0, goal=ST0)).status is (
        ControlStatus.OK
    )
    last, dt = c._last, SPEC.period
    assert last is not None and last.p is not None and last.v is not None
    caps = ((2 * dt, 30.0, cap),)
    obs = Observation("r08", 1, dt, *last.p[1], *last.v[1], goal=ST0, job="j00011", speed_caps=caps)
    assert np.abs(last.v[1]).max() <= 0.2  # within the cap now; the plan speeds on
    assert np.abs(last.v[2:]).max() > 0.2
    report = SolveReport(SolverOutcome.INFEASIBLE, 0.0, 0.0)
    cmd, kept = fall_back(obs, SPEC, c.horizon, floor, last, True, True, report)
    assert cmd.status is ControlStatus.FALLBACK and cmd.solve is report
    vx, vy = obs.vx + dt * cmd.ax, obs.vy + dt * cmd.ay
    if cap < 1.0:  # the plan breaks the cap: a brake (before: the plan, on to 1.02 m/s)
        assert kept is None
        assert abs(vx) <= abs(obs.vx) and abs(vy) <= abs(obs.vy)
    else:  # within a cap it keeps: the plan, one step on
        assert kept is not None and np.array_equal(kept.p, np.vstack([last.p[1:], last.p[-1:]]))
        assert (vx, vy) == pytest.approx(tuple(last.v[2]))

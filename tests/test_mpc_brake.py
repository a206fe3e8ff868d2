"""When the MPC has no plan to follow (plugins/mpc/fallback.py): braking stays in the free space,
judged with shapely from the obstacle's own polygon (the case a fuzz floor found, s41-0109: a
robot held while skimming a rotated wall, and random approaches to that wall); a plan that keeps
a robot where it is, off its goal with nobody about (or only robots standing still), is a
trap (`stays_put`, s41-0086)."""

from __future__ import annotations

import math
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import assume, event, given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Polygon, box

from fleet.floor import FloorSpec, Obstacle, SpeedZone, compile_floor
from fleet.plugins import ControlStatus, Neighbour, Observation, RobotSpec
from fleet.plugins.robot import DoubleIntegrator
from fleet_plugins.mpc.fallback import brake, braking_path, free_brake, stays_put, within_zones
from fleet_plugins.mpc.neighbours import brake_runs_into
from tests.scripts import load_script

#: The wall of fuzz floor s41-0109 (a thin band at -36 degrees) and that run's robot.
WALL = Polygon([(33.6621, 46.4239), (26.883, 51.382), (26.7062, 51.1403), (33.4853, 46.1822)])
RADIUS = 0.361
SPEC = RobotSpec(radius=RADIUS, v_max=1.29, a_max=1.63, period=0.25)
FLOOR = compile_floor(
    FloorSpec(
        source="<test rotated wall>",
        name="rotated wall",
        boundary=box(15.0, 40.0, 40.0, 60.0),
        default_v_max=(1.05, 1.05),
        clearance=RADIUS,
        obstacles=(Obstacle("wall0_1", WALL),),
    )
)
HORIZON = 12


def driven(obs: Observation, floor=FLOOR) -> list[tuple[float, float]]:
    """Where the robot goes, braking tick after tick as `brake` says, until at rest."""
    model = DoubleIntegrator(SPEC.period, SPEC.a_max)
    x, y, vx, vy = obs.x, obs.y, obs.vx, obs.vy
    out = [(x, y)]
    for k in range(200):
        now = Observation("r02", k, obs.t + k * SPEC.period, x, y, vx, vy)
        cmd = brake(now, SPEC, HORIZON, ControlStatus.OK, floor)
        x, y, vx, vy = model.step(x, y, vx, vy, cmd.ax, cmd.ay)
        out.append((x, y))
        if vx == vy == 0.0:
            return out
    pytest.fail("never came to rest")


def gap_to_wall(points: list[tuple[float, float]]) -> float:
    """The least distance from the robot's centre to the wall, along the straight steps."""
    return float(shapely.distance(LineString(points), WALL))


def test_a_robot_held_while_skimming_a_wall_brakes_clear_of_it() -> None:
    # The state of s41-0109's r02 at t = 57.0 s: braking along the line of travel ends
    # 0.6 mm into the wall (the robot stood there for the rest of the run).
    obs = Observation("r02", 228, 57.0, 28.602400004, 49.303622422514, 0.567499984, -0.404717690)
    straight = driven(obs, floor=None)
    assert gap_to_wall(straight) < RADIUS - 1e-4  # the old brake: into the wall
    assert gap_to_wall(driven(obs)) >= RADIUS - 1e-6


@settings(max_examples=200, deadline=None)
@given(
    along=st.floats(0.1, 0.9),
    off=st.floats(0.0, 0.01),
    speed=st.floats(0.05, 1.29),
    angle=st.floats(-0.1, 0.1),
)
def test_braking_near_the_wall_never_enters_it(along, off, speed, angle) -> None:
    # A robot whose next step (fixed already: p += dt * v) ends `off` outside the wall's
    # lower face, heading along it at a slight angle (towards it or away), at up to full
    # speed, as an MPC plan hugging the wall leaves it: wherever braking can stay clear, it
    # does.
    (x0, y0), (x1, y1) = (26.7062, 51.1403), (33.4853, 46.1822)
    length = math.hypot(x1 - x0, y1 - y0)
    ux, uy = (x1 - x0) / length, (y1 - y0) / length
    nx, ny = uy, -ux  # the outward normal of the lower face
    hx = ux * math.cos(angle) - uy * math.sin(angle)
    hy = ux * math.sin(angle) + uy * math.cos(angle)
    vx, vy = speed * hx, speed * hy
    assume(max(abs(vx), abs(vy)) <= SPEC.v_max)
    qx = x0 + along * (x1 - x0) + (RADIUS + off) * nx
    qy = y0 + along * (y1 - y0) + (RADIUS + off) * ny
    px, py = qx - SPEC.period * vx, qy - SPEC.period * vy
    assume(gap_to_wall([(px, py), (qx, qy)]) >= RADIUS)
    obs = Observation("r02", 0, 0.0, px, py, vx, vy)
    ours, straight = gap_to_wall(driven(obs)), gap_to_wall(driven(obs, None))
    # Clear of the wall, judged on its own polygon (2,000 examples: braking along the line of
    # travel alone ran into it in 6 % of them).
    clear = RADIUS - 1e-6
    event("straight clear" if straight >= clear else "rescued")
    assert ours >= clear, (ours, straight)


# --- a plan that keeps the robot where it is --------------------------------------------------


def at(x: float, y: float, **kw) -> Observation:
    return Observation("r02", 0, 0.0, x, y, kw.pop("vx", 0.0), kw.pop("vy", 0.0), **kw)


def test_a_plan_that_keeps_a_robot_at_rest_off_its_goal_with_nobody_about_stays_put() -> None:
    # Fuzz s41-0086: pushed off its reference, the robot's every solve was optimal and kept
    # it where it was, 3.6 m from the reference, for the last 90 s; such a plan now starts a
    # new trip from there (the case then delivers all 4 jobs).
    here = np.array([[28.0, 49.0]] * (HORIZON + 1))
    goal = (20.0, 45.0)
    assert stays_put(at(28.0, 49.0), here, goal, RADIUS)
    moving = here.copy()
    moving[1:, 0] += 0.01
    assert not stays_put(at(28.0, 49.0), moving, goal, RADIUS)  # the plan moves it
    assert not stays_put(at(28.0, 49.0, vx=0.1), here, goal, RADIUS)  # not at rest
    assert not stays_put(at(28.0, 49.0), here, (28.2, 49.1), RADIUS)  # on its goal
    assert not stays_put(at(28.0, 49.0, speed_cap=0.0), here, goal, RADIUS)  # held by a cap
    other = Neighbour("r01", 30.0, 49.0, 0.2, 0.0, RADIUS, 1, ())
    assert not stays_put(at(28.0, 49.0, neighbours=(other,)), here, goal, RADIUS)  # waits
    # One standing still changes nothing from tick to tick: `test_mpc_stand_still.py`.


def test_a_plan_that_sets_off_only_later_with_nobody_about_stays_put_too() -> None:
    # Fuzz s91-0759: 3.3 m off its reference, each solve's optimal plan kept the robot at rest
    # for 4 steps or more and moved only later; followed for 4 ticks and solved again alike,
    # it never set off (the last 90 s of the run). Judged over this tick (the first input).
    goal = (10.96, -9.72)
    later = np.array([[2.93, -13.9]] * (HORIZON + 1))
    later[5:, 1] += 0.05 * np.arange(1, HORIZON - 3)
    assert stays_put(at(2.93, -13.9), later, goal, RADIUS)
    now = np.array([[2.93, -13.9]] * (HORIZON + 1))
    now[2:, 1] += 0.01 * np.arange(1, HORIZON)  # sets off this tick: p[2] moves
    assert not stays_put(at(2.93, -13.9), now, goal, RADIUS)


def test_a_robot_held_in_a_door_solves_rather_than_brake_out_of_the_free_space(tmp_path):
    # Fuzz case s31-0665 (run cut to 40 s): r01 drove through a door between two walls on a
    # plan that turned there when r02, which it outranks, came close (`must_hold`: follow the
    # plan or brake). Its plan no longer kept clear of r02's, so it braked straight on, 0.1 m
    # out of the free space, and every solve from there was infeasible: 70 fallbacks and 68
    # obstacle steps by the engine's own checker. A held robot whose every brake leaves the
    # free space now solves (`neighbours.brake_runs_into` with the floor).
    case = Path(__file__).resolve().parent / "safety_cases" / "held_in_a_door"
    shutil.copytree(case, tmp_path / "case")
    outcome = load_script("fuzz_floors").run_folder(tmp_path / "case")
    assert outcome.status == "ok", outcome.findings
    assert outcome.engine["obstacle"] == 0
    assert outcome.engine["fallbacks"] <= 2


def test_a_robot_whose_brake_would_enter_a_slower_zone_too_fast_solves_instead() -> None:
    # Fuzz case s21-0854: r01, held (a lower robot close), braked straight on at 0.95 m/s^2
    # from 0.8425 m/s and crossed into a 0.52 m/s zone at 0.605 m/s. A brake knows no zones:
    # a held robot whose brake would break one solves instead (`brake_runs_into`).
    spec = RobotSpec(radius=0.413, v_max=1.22, a_max=0.95, period=0.25)
    floor = compile_floor(
        FloorSpec(
            source="<test slow zone ahead>",
            name="slow zone ahead",
            boundary=box(0.0, 0.0, 30.0, 10.0),
            default_v_max=(1.22, 1.22),
            clearance=spec.radius,
            zones=(SpeedZone("slow", box(20.0, 0.0, 30.0, 10.0), (0.52, 0.52)),),
        )
    )
    # 0.8425 m/s, 0.3 m short of the zone: braking covers 0.21 m and 0.15 m in the next two
    # steps, the second into the zone at 0.605 m/s.
    near = Observation("r01", 0, 0.0, 19.7, 5.0, 0.8425, 0.0)
    assert not within_zones(floor, spec, free_brake(near, spec, floor)[2])
    assert brake_runs_into(near, spec, HORIZON, floor)
    # Far enough off, or slow enough, the brake keeps within the zone's limit.
    for obs in (replace(near, x=17.0), replace(near, vx=0.5)):
        assert within_zones(floor, spec, free_brake(obs, spec, floor)[2])
        assert not brake_runs_into(obs, spec, HORIZON, floor)
    # Without the floor nothing is known of zones (nor of walls).
    assert not brake_runs_into(near, spec, HORIZON)


@pytest.mark.parametrize("neighbours", [(), (Neighbour("r2", 30.0, 45.0, 0.0, 0.0),)])
def test_a_speed_under_the_rest_threshold_is_cancelled_not_left_to_drift(neighbours):
    # Fuzz s42-0010: -8.4e-10 m/s, under REST_SPEED, was left alone by every brake and
    # carried the robot across a region's edge over a minute.
    obs = Observation("r1", 0, 0.0, 20.0, 45.0, -8.4e-10, 3e-10, neighbours=neighbours)
    cmd = brake(obs, SPEC, HORIZON, ControlStatus.FALLBACK, FLOOR)
    robot = DoubleIntegrator(SPEC.period, SPEC.a_max)
    _, _, vx, vy = robot.step(obs.x, obs.y, obs.vx, obs.vy, cmd.ax, cmd.ay)
    assert (vx, vy) == (0.0, 0.0)
    assert bool(cmd.plan) == bool(neighbours)
    assert all((x, y) == (obs.x, obs.y) for _, x, y in cmd.plan)


def test_a_fallback_brake_keeps_out_of_a_slower_zone_when_another_brake_can() -> None:
    # 80 MPC robots on the fleet scenario (seed 1, with neighbours.ahead_in_queue): r39's solve
    # at 87 s was infeasible at (1.0, 0.379) m/s, and braking along its line of travel took it
    # into a 0.4 m/s zone at 0.875 m/s (4 samples); braking both axes at the full rate stays out.
    spec = RobotSpec(v_max=1.0, a_max=0.5, radius=0.4, period=0.25)
    floor = compile_floor(
        FloorSpec(
            source="<zone above>",
            name="zone above",
            boundary=box(0.0, 20.0, 30.0, 30.0),
            default_v_max=(1.0, 1.0),
            clearance=spec.radius,
            zones=(SpeedZone("slow", box(19.0, 25.9, 30.0, 30.0), (0.4, 0.4)),),
        )
    )
    obs = Observation("r39", 348, 87.0, 19.301, 25.589, 1.0, 0.379)
    cmd = brake(obs, spec, HORIZON, ControlStatus.FALLBACK, floor)
    x, y, vx, vy = obs.x, obs.y, obs.vx, obs.vy
    path = [(obs.t, x, y)]
    robot = DoubleIntegrator(spec.period, spec.a_max)
    x, y, vx, vy = robot.step(x, y, vx, vy, cmd.ax, cmd.ay)
    path.append((obs.t + spec.period, x, y))
    assert within_zones(floor, spec, tuple(path))
    assert within_zones(floor, spec, free_brake(obs, spec, floor)[2])
    # Not vacuous: straight on, the robot enters the zone too fast.
    straight = braking_path(obs.t, obs.x, obs.y, obs.vx, obs.vy, spec.period, spec.a_max, 100)
    assert not within_zones(floor, spec, straight)

"""Solving less (issue 17): the MPC follows its previous plan, one step on, while nothing has
happened (`MPCController(reuse_ticks=...)`), and solves again on an event: a deviation, print
caps the plan breaks, another robot within reach, or the plan's age. Real solves, real loops.
"""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

from fleet.engine import World
from fleet.errors import PluginError
from fleet.plugins import ControlStatus, Observation, load_controller
from fleet.plugins.robot import DoubleIntegrator, brake_input
from fleet.printing import CapSchedule
from fleet.scenario import PluginChoice
from fleet_plugins.mpc import MPCController
from fleet_plugins.mpc.neighbours import brake_runs_into, must_hold
from fleet_plugins.mpc.reuse import RepeatWatch
from tests.test_fleet import mpc_fleet_run, mpc_fleet_scenario
from tests.test_mpc import L_HALL, SPEC_1S, Loop, l_hall
from tests.test_mpc_fleet import CONTACT, Run, crossing, far_away, parked
from tests.test_queueing import run as run_to_one_station


def unsolved_runs(solved: list[bool]) -> list[int]:
    """Lengths of the runs of ticks without a solve."""
    runs, n = [], 0
    for s in solved:
        if s:
            if n:
                runs.append(n)
            n = 0
        else:
            n += 1
    return runs + ([n] if n else [])


def test_reusing_the_plan_skips_solves_and_keeps_zones_and_caps() -> None:
    # The slow zone round the machine and a cap while approaching it: the same trip as with a
    # solve every tick, without a violation, arriving, with most ticks of cruising not solved.
    caps = CapSchedule(((6.0, 21.0, 0.2),))
    goal = (18.0, 2.0)
    loop = Loop.start(
        MPCController(horizon=8, reuse_ticks=3), l_hall(zone=True), (2.0, 9.5), SPEC_1S, caps=caps
    )
    assert loop.drive(goal, limit=100), f"stuck at {loop.p}"
    assert loop.violations() == []
    moving = [c for c in loop.commands if c.plan and c.plan[0][1:] != c.plan[-1][1:]]
    solved = [c.solve is not None for c in moving]
    assert loop.controller.reuses > len(moving) // 3  # it really skipped solves
    assert max(unsolved_runs(solved)) <= 3  # never older than reuse_ticks
    for c in loop.commands:
        assert c.status is ControlStatus.OK
    # Every solve's plan is solved afresh (the warm start from a followed plan included).
    assert all(c.solve.outcome.usable for c in loop.commands if c.solve is not None)


def at_a_reuse(reuse: int) -> Loop:
    """A robot driving along the hall that has just followed its plan instead of solving, and
    would follow it once more."""
    loop = Loop.start(MPCController(horizon=8, reuse_ticks=reuse), L_HALL, (2.0, 5.0), SPEC_1S)
    goal = (18.0, 5.0)
    for _ in range(4):
        loop.step(goal)
    while loop.commands[-1].solve is None:
        loop.step(goal)
    loop.step(goal)
    assert loop.commands[-1].solve is None
    return loop


def test_caps_the_plan_breaks_bring_a_solve() -> None:
    loop = at_a_reuse(4)
    # A cap from two steps on at half the plan's speed there: the plan breaks it, so the robot
    # solves (with no new cap it would have followed the plan once more).
    last = loop.controller._last
    assert last is not None and last.v is not None
    cap = 0.5 * float(np.max(np.abs(last.v[3:])))
    assert cap > 0.1
    now = loop.now
    loop.caps = CapSchedule(((now + 2.0, now + 30.0, cap),))
    assert loop.step((18.0, 5.0)).solve is not None
    for _ in range(30):
        loop.step((18.0, 5.0))
    assert loop.violations() == []


def test_a_deviation_from_the_plan_brings_a_solve() -> None:
    loop = at_a_reuse(4)
    loop.p = loop.p + np.array([0.0, 0.01])  # pushed 1 cm off the plan
    assert loop.step((18.0, 5.0)).solve is not None


def test_without_an_event_the_plan_is_followed_until_its_age() -> None:
    loop = at_a_reuse(3)
    assert loop.step((18.0, 5.0)).solve is None  # the second tick without a solve
    assert loop.step((18.0, 5.0)).solve is None  # the third
    assert loop.step((18.0, 5.0)).solve is not None  # reuse_ticks reached


@pytest.mark.parametrize("reuse", [2, 6])
def test_a_crossing_robot_is_kept_clear_of_with_plans_reused(reuse: int) -> None:
    # As with a solve every tick: outside the square of r_i + r_j + margin at every step of
    # every plan followed, solved or reused; the crossing robot brings solves, the rest not.
    run = Run(MPCController(horizon=12, reuse_ticks=reuse), crossing)
    assert run.drive(80)
    for cmd in run.commands:
        assert cmd.status is ControlStatus.OK
        plan = np.array(cmd.plan)
        there = np.array([crossing(t) for t in plan[:, 0]])
        sep = np.max(np.abs(plan[1:, 1:] - there[1:]), axis=1)
        assert np.all(sep >= CONTACT + 0.1 - 1e-6), sep.min()
    assert min(run.gaps) >= CONTACT + 0.1 - 1e-6
    assert run.controller.reuses > 0
    assert sum(b > 0 for b in run.controller.separation_binaries) >= 5


def test_a_robot_out_of_reach_does_not_stop_the_reuse() -> None:
    run = Run(MPCController(horizon=8, reuse_ticks=4), far_away)
    assert run.drive(80)
    solved = [c.solve is not None for c in run.commands]
    assert run.controller.reuses >= len(run.commands) // 2
    assert max(unsolved_runs(solved)) <= 4


def test_the_default_reuses_4_ticks_and_stays_below_a_short_horizon() -> None:
    assert MPCController().reuse_ticks == 4
    assert MPCController(horizon=5).reuse_ticks == 4
    assert MPCController(horizon=4).reuse_ticks == 3  # a plan followed N ticks has run out
    assert MPCController(horizon=2).reuse_ticks == 1
    assert MPCController(reuse_ticks=0).reuse_ticks == 0
    assert load_controller("mpc", {"horizon": 3}).reuse_ticks == 2  # type: ignore[attr-defined]


@pytest.mark.parametrize("value", [-1, 1.5, True, "2", 25])
def test_a_bad_reuse_ticks_is_refused(value: object) -> None:
    with pytest.raises(ValueError, match=f"reuse_ticks = {re.escape(repr(value))}: must"):
        MPCController(reuse_ticks=value)  # type: ignore[arg-type]
    with pytest.raises(PluginError, match="'mpc'.*reuse_ticks"):
        load_controller("mpc", {"reuse_ticks": value})


def test_a_fleet_reusing_plans_is_safe_and_the_same_with_0_and_2_workers() -> None:
    # Through the engine: 6 MPC robots on the shop floor with reuse, in this process and in
    # two worker processes: the same digest (a reuse depends on the observation only), no
    # violation, and fewer solves than the same fleet solving every tick.
    base = mpc_fleet_scenario()  # the shipped fleet.toml, 6 robots, 120 s, solving every tick
    reusing = replace(base, controller=PluginChoice("mpc", {"reuse_ticks": 4}))
    results = [World(reusing, workers=w).run() for w in (0, 2)]
    summaries = [r.summary for r in results]
    for result, s in zip(results, summaries, strict=True):
        assert set(s["solver"]["termination"]) == {"optimal"}  # none cut by the wall clock
        assert sum(s["violations"].values()) == 0, result.safety.examples
    assert summaries[0]["digest"] == summaries[1]["digest"]
    every_tick = mpc_fleet_run(0).summary  # `base` in this process, shared with test_fleet.py
    assert summaries[0]["solver"]["steps"] < 0.6 * every_tick["solver"]["steps"]
    assert summaries[0]["jobs"]["completed"] >= every_tick["jobs"]["completed"] - 1 >= 0


def driving_east(t: float, y: float = 5.0) -> tuple[float, float]:
    """A robot along y at 1 m/s, at x = 6 at t = 0."""
    return (6.0 + t, y)


def test_a_robot_waiting_at_rest_does_not_count_as_a_cycle() -> None:
    # A robot standing in a queue, or held a tick by the start gate, solves from the same
    # state again: not a cycle (`RepeatWatch`), so it keeps reusing its plan between solves;
    # a robot that moves and comes back to a state a solve started from is one.
    watch, trip = RepeatWatch(), object()
    here = Observation("r1", 0, 0.0, 3.0, 4.0, 0.0, 0.0)
    for _ in range(5):
        assert not watch.solved_from(here, trip)
        watch.waited(here, 0.0, 0.0, 0.25)  # kept at rest
    assert not watch.solved_from(here, trip)
    watch.waited(here, 0.5, 0.0, 0.25)  # sets off: its state is kept
    assert watch.solved_from(here, trip)
    # Moving, the state is always kept.
    moving, other = Observation("r1", 0, 0.0, 3.0, 4.0, 0.2, 0.0), object()
    assert not watch.solved_from(moving, other)
    watch.waited(moving, -0.8, 0.0, 0.25)  # (brakes to rest within the tick)
    assert watch.solved_from(moving, other)


def test_a_robot_waiting_at_the_margin_of_a_parked_one_keeps_its_plan() -> None:
    # Driving up to a robot parked on its goal, the robot stops at the soft margin (r_i + r_j
    # + 0.1 m, to rounding: 0.8999999999999986 m) and waits there. Its plan at rest keeps that
    # distance, so it is followed between solves (every tick was solved when the rounding
    # counted as entering the margin), and it never comes closer.
    run = Run(MPCController(horizon=12, reuse_ticks=4), parked)
    for _ in range(60):
        run.step((10.0, 5.0))
    waiting = run.commands[30:]
    assert np.max(np.abs(run.v)) <= 1e-9 and abs(run.p[0] - 9.1) < 1e-6  # at the margin
    assert sum(c.solve is not None for c in waiting) <= len(waiting) // 4
    assert min(run.gaps) >= CONTACT + 0.1 - 1e-6


def test_a_held_robot_follows_its_plan_only_where_it_can_still_brake_a_tick_later(
    tmp_path, monkeypatch
) -> None:
    # Three MPC robots to one station (tests/test_queueing.py): r01 > r02 > r03 converge on
    # the station's line, r01 and r03 from either side, r02 on it. r03 is close, so r02 is held
    # (it follows its plan or brakes); r02 is close, so r01 is held too and drives on along its
    # plan. At 10.0 s r02 followed its plan, braked at 10.25 s, and at 10.5 s its brake ran into
    # r01's, r01 a tick farther on (0.742 m, radii 0.4): it solved from there, infeasibly, 2
    # fallbacks; 4 in the run, r01 and r02 0.856 m apart at the closest. Now a held robot follows
    # its plan only if braking from its next state keeps clear of r01 braking then too
    # (`reuse.brake_keeps_clear`): r02 braked from 10.0 s; 1 fallback, 0.896 m.
    # Judged from the engine's observations: whenever a held robot followed its plan, its brake
    # from there keeps clear of the robots that outrank it a tick on and two ticks on.
    seen: dict[tuple[str, float], tuple[Observation, bool]] = {}
    compute = MPCController.compute

    def logged(self: MPCController, obs: Observation):
        reuses = self.reuses
        hold = must_hold(obs, self.context.spec, self.horizon, self.separation_margin_m)
        cmd = compute(self, obs)
        seen[(obs.robot, round(obs.t, 6))] = (obs, hold and self.reuses > reuses)
        return cmd

    monkeypatch.setattr(MPCController, "compute", logged)
    world, summary = run_to_one_station(tmp_path, "mpc", queue=True)
    assert summary["violations"]["collision"] == 0
    spec = world.robots["r02"].spec
    dt, robot = spec.period, DoubleIntegrator(spec.period, spec.a_max)
    held = 0
    for (rid, t), (_, reused) in seen.items():
        on = seen.get((rid, round(t + dt, 6)))
        later = seen.get((rid, round(t + 2 * dt, 6)))
        if not reused or on is None or later is None:
            continue
        held += 1
        state = on[0]  # on the plan it followed
        assert not brake_runs_into(state, spec, 25), (rid, t)
        ax, ay = brake_input(state.vx, state.vy, dt, spec.a_max)
        x, y, vx, vy = robot.step(state.x, state.y, state.vx, state.vy, ax, ay)
        braking = replace(later[0], x=x, y=y, vx=vx, vy=vy)  # a tick into its brake
        assert not brake_runs_into(braking, spec, 25), (rid, t)
    assert held >= 10  # not vacuous: held robots followed their plans

"""An MPC robot trapped at a region's edge sets off although robots stand in sight (issue 16,
MPC fuzz case s51-0144).

r08 (job to st4 from 66 s), pushed off its reference while it went round other robots, came to
rest at the edge of a thin triangular region, 1.2 m from its reference, which crossed that edge
further on into a strip only the edge's far end meets. Staying was every solve's optimum (the
reference's regions lay beyond the horizon along the edge), and `fallback.stays_put` would have
planned a new trip from there, but not with a robot in sight: r01, idle and at rest 3.1 m away.
r08 stood there for 100 s. A robot standing still (at rest, its plan too) changes nothing from
one tick to the next, so it no longer stops the new trip; one that moves still does, and so
does any robot once the trip was planned from that very spot. The case folder is
tests/liveness_cases/mpc_at_a_region_edge (as found: `scripts/fuzz_floors.py --controller mpc
--fleet 4-8 --seed 51 --only 144`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fleet.floor import load_floor
from fleet.paths import PathPlanner
from fleet.plugins import (
    ControllerContext,
    ControlStatus,
    Neighbour,
    Observation,
    RobotSpec,
    SolverOutcome,
)
from fleet_plugins.mpc.controller import MPCController
from fleet_plugins.mpc.fallback import stays_put
from fleet_plugins.mpc.model import Solution

CASE = Path(__file__).resolve().parent / "liveness_cases" / "mpc_at_a_region_edge"
SPEC = RobotSpec(v_max=0.89, a_max=0.41, radius=0.405, period=0.2)
START = (-10.749464193, -51.538364181)  # where r08's trip of 79.2 s was planned
STUCK = (-11.85087637178445, -52.026248537037745)  # where it stood from 101 s on, at rest
GOAL = (-14.9378, -27.8975)  # st4
R01 = (-9.3174286, -50.179075141)  # idle, at rest


def standing(t: float) -> Neighbour:
    """r01 as r08 saw it: at rest, its plan keeping it there."""
    plan = ((t, *R01), (t + 4.8, *R01))
    return Neighbour("r01", *R01, 0.0, 0.0, radius=0.405, priority=8, plan=plan)


def test_a_robot_trapped_at_a_region_edge_sets_off_past_one_standing_in_sight() -> None:
    floor = load_floor(CASE / "floor.toml")
    c = MPCController()
    c.reset(ControllerContext("r08", SPEC, floor, PathPlanner(floor, SPEC.v_max, SPEC.a_max)))
    first = c.compute(Observation("r08", 396, 79.2, *START, 0.0, 0.0, goal=GOAL, job="j00014"))
    assert first.solve is not None and first.solve.outcome.usable
    trip = c._trip
    assert trip is not None
    # The state the run was in: at rest on its previous plan, at rest in the one region that
    # holds it, its progress the sample where the reference crosses into the strip.
    here = trip.holding(np.array(STUCK))
    assert len(here) == 1
    N, t = c.horizon, 130.6
    c._last = Solution(
        SolverOutcome.OPTIMAL,
        0.0,
        p=np.tile(STUCK, (N + 1, 1)),
        v=np.zeros((N + 1, 2)),
        u=np.zeros((N, 2)),
        regions=np.full(N - 1, next(iter(here))),
    )
    c._last_t, c._last_model, c._progress = t - SPEC.period, c._model, 6
    x, y, vx, vy = *STUCK, 0.0, 0.0
    for tick in range(20):  # 4 s of the double integrator, as the engine steps it
        obs = Observation(
            "r08",
            653 + tick,
            t,
            x,
            y,
            vx,
            vy,
            goal=GOAL,
            job="j00014",
            neighbours=(standing(t),),
        )
        cmd = c.compute(obs)
        assert cmd.status is ControlStatus.OK
        x, y = x + SPEC.period * vx, y + SPEC.period * vy
        vx, vy = vx + SPEC.period * cmd.ax, vy + SPEC.period * cmd.ay
        t += SPEC.period
    # A new trip from where it stood, and it drove off on it, towards its goal to the north.
    # Before, every solve was optimal and kept it within a micrometre of STUCK.
    assert c.trips == 2
    assert math.dist((x, y), STUCK) > 0.5
    assert y > STUCK[1] + 0.3


def test_only_robots_standing_still_leave_a_trap_a_trap() -> None:
    here = np.tile(STUCK, (26, 1))
    at_rest = Observation("r08", 0, 130.6, *STUCK, 0.0, 0.0, neighbours=(standing(130.6),))
    assert stays_put(at_rest, here, GOAL, SPEC.radius, np.array(START))
    # A robot that will move may be what this one waits for.
    leaving = Neighbour("r01", *R01, 0.0, 0.0, plan=((130.6, *R01), (131.0, R01[0] + 0.1, R01[1])))
    moving = Neighbour("r01", *R01, 0.2, 0.0)
    for other in (leaving, moving):
        seen = Observation("r08", 0, 130.6, *STUCK, 0.0, 0.0, neighbours=(other,))
        assert not stays_put(seen, here, GOAL, SPEC.radius, np.array(START))
    # A trip planned from this very spot would only be planned again, the same.
    assert not stays_put(at_rest, here, GOAL, SPEC.radius, np.array(STUCK))

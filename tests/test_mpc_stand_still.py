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
from fleet.plugins import Neighbour, Observation, RobotSpec
from fleet_plugins.mpc.fallback import stays_put
from tests.mpc_trapped import at_rest_on_its_plan, drive, planned

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
    c = planned(floor, "r08", SPEC, START, GOAL, 79.2, 396, "j00014")
    # The state the run was in: at rest on its previous plan, at rest in the one region that
    # holds it, its progress the sample where the reference crosses into the strip.
    at_rest_on_its_plan(c, STUCK, 130.6, 6)
    x, y = drive(c, STUCK, 130.6, 653, 20, GOAL, "j00014", lambda t: (standing(t),))  # 4 s
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

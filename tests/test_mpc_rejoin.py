"""An MPC robot off its reference past a corner still finds its way on (issue 16, MPC fuzz
case s21-0087).

r02, going round r03 parked north of it, took the other side of a zone's corner from its
reference and stopped in the zone's tip at (19.73, -27.65). The nearest reference sample (the
robot's progress) lay past the corner, so the corridor held only the chords past it, whose
regions do not meet the zone's; only the previous plan's region held the robot. Every solve was
optimal at rest, r01 and r03 in sight kept `fallback.stays_put` off, and r02 stood there with
its job for the last 155 s of 200 (and of an 800-s run). The corridor now opens back to the
chord that holds the robot (`horizon.rejoin`). The case folder is
tests/liveness_cases/mpc_past_a_corner (as found).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fleet.floor import load_floor
from fleet.plugins import Neighbour, RobotSpec
from tests.mpc_trapped import at_rest_on_its_plan, drive, planned

CASE = Path(__file__).resolve().parent / "liveness_cases" / "mpc_past_a_corner"
SPEC = RobotSpec(v_max=0.97, a_max=1.58, radius=0.405, period=0.5)
START = (18.37088564286263, -31.3727)  # r02's start, where its trip to st4 was planned
STUCK = (19.731, -27.6504)  # where it stood from 41 s on, at rest
GOAL = (25.2156, -35.9734)  # st4
# r03 as it stood then, parked 4.3 m away: a robot in sight, so `stays_put` does not apply.
R03 = Neighbour("r03", 18.37, -31.52, 0.0, 0.0, radius=0.405, priority=1)


def test_a_robot_in_a_region_its_progress_has_passed_drives_on() -> None:
    floor = load_floor(CASE / "floor.toml")
    c = planned(floor, "r02", SPEC, START, GOAL, 31.0, 62, "j00002")
    trip = c._trip
    assert trip is not None
    # The progress (the nearest sample) is past the corner: none of the chords round it
    # overlaps the region the robot stands in.
    here = trip.holding(np.array(STUCK))
    near = int(trip.progress(np.array([STUCK]), 0, 8)[0])
    assert len(here) == 1 and not here & trip.corridor(near - 1, near + 1)
    # The state the run was in: at rest on its previous plan, a plan at rest in that region.
    at_rest_on_its_plan(c, STUCK, 45.0, near)
    # 6 s of the double integrator, as the engine steps it.
    x, _ = end = drive(c, STUCK, 45.0, 90, 12, GOAL, "j00002", lambda t: (R03,))
    # It drove on along its route, east past the corner. On main every solve was optimal and
    # kept it within a millimetre of STUCK.
    assert math.dist(end, STUCK) > 1.0
    assert x > STUCK[0] + 1.0

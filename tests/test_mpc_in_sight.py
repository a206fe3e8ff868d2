"""An MPC robot's progress along its reference does not jump across a wall (issue 16, MPC fuzz
case s73-0631).

A wall with one gap splits the floor; r08's trip from (43.28, 30.61), north of the wall, to
st6, south of it, runs 12 m east to the gap and 12 m back west on the other side. Waiting at
the gap for robots coming through it, r08 backed off 1.6 m, and the nearest reference sample
as the crow flies was then one past the gap, 1.6 m away through the wall. Its progress jumped
there; it tracked the stretch back west from the wrong side of the wall and came to rest
against it right above st6: still with its job for the last 550 s of a 780-s run, the robots
sent aside for it to no effect. Progress now counts only samples whose chord the robot can see
(`Trip.progress_in_sight`). The case folder is tests/liveness_cases/mpc_across_a_wall (as
found; 8 MPC robots for 180 s, too slow for the suite).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fleet.floor import load_floor
from fleet.plugins import Observation, RobotSpec
from tests.mpc_trapped import at_rest_on_its_plan, drive, planned

CASE = Path(__file__).resolve().parent / "liveness_cases" / "mpc_across_a_wall"
SPEC = RobotSpec(v_max=1.14, a_max=1.83, radius=0.307, period=0.396)
START = (43.2827, 30.6107)  # where r08's trip to st6 was planned
GOAL = (43.2827, 24.2543)  # st6, across the wall from START
BACKED_OFF = (53.16, 34.04)  # where r08 stood after backing off from the gap
AT_THE_GAP = 28  # its progress then: the sample at the gap's mouth


def test_progress_stays_on_the_robots_side_of_the_wall() -> None:
    floor = load_floor(CASE / "floor.toml")
    trip = planned(floor, "r08", SPEC, START, GOAL, 130.0, 328, "j00005")._trip
    assert trip is not None
    point = np.array(BACKED_OFF)
    # As the crow flies, the nearest sample is one past the gap, on the far side of the wall.
    crow = int(trip.progress(point[None, :], AT_THE_GAP, 8)[0])
    assert crow > AT_THE_GAP and not trip.chord_sets[crow] & trip.holding(point)
    # None of the window's chords is in sight (the robot backed off from the gap): it stays.
    assert trip.progress_in_sight(point, AT_THE_GAP, 8) == (AT_THE_GAP, False)
    # On its own side, ahead of the gap, progress still moves on to the nearest sample.
    on_the_way = trip.reference.positions[20]
    assert trip.progress_in_sight(on_the_way, 15, 8) == (20, True)


def test_out_of_sight_of_the_chords_ahead_the_reference_waits_at_the_progress() -> None:
    floor = load_floor(CASE / "floor.toml")
    c = planned(floor, "r08", SPEC, START, GOAL, 130.0, 328, "j00005")
    at_rest_on_its_plan(c, BACKED_OFF, 164.0, AT_THE_GAP)
    assert c._trip is not None
    obs = Observation("r08", 414, 164.0, *BACKED_OFF, 0.0, 0.0, goal=GOAL, job="j00005")
    data, _ = c._step_data(obs)
    # Every step tracks the gap's mouth, at rest: run on through the gap, the window would
    # pull the robot along the wall's other side as the crow flies.
    mouth = c._trip.reference.positions[AT_THE_GAP]
    assert np.allclose(data.p_ref, mouth) and np.allclose(data.v_ref, 0.0)
    # Back in sight of the chords ahead, the window runs on again.
    obs = Observation("r08", 414, 164.0, *mouth, 0.0, 0.0, goal=GOAL, job="j00005")
    data, _ = c._step_data(obs)
    assert math.dist(data.p_ref[-1], mouth) > 3.0


def test_a_robot_backed_off_from_a_gap_goes_through_it() -> None:
    floor = load_floor(CASE / "floor.toml")
    c = planned(floor, "r08", SPEC, START, GOAL, 130.0, 328, "j00005")
    at_rest_on_its_plan(c, BACKED_OFF, 164.0, AT_THE_GAP)
    # 24 s of the double integrator, no other robot in sight.
    end = drive(c, BACKED_OFF, 164.0, 414, 60, GOAL, "j00005", lambda t: ())
    # Back to the gap's mouth (the reference waits there while the robot cannot see the
    # chords ahead), through the gap and back west to st6 (about 18 s). With the progress
    # across the wall it drove west on the wrong side of it, to (43.54, 30.70) at 16 s, 6.5 m
    # from st6 with the wall between, and was still 7.2 m from it at 24 s.
    assert math.dist(end, GOAL) < 0.1

"""A softened square never lets a plan into contact (issue 16, MPC fuzz case s51-0000).

Seven MPC robots (radii 0.44, period 0.25 s, `scripts/fuzz_floors.py --controller mpc --fleet
4-8 --seed 51 --only 0`). r03 (lower) drove past r01, at rest, off on r01's diagonal: inside
r01's square but out of contact, so its solve kept to a side across the line between the two
(`separation.build_separation`). That was infeasible, and the solve was tried again with r01's
whole square soft (`crowd.solve_clear`), which planned r03 0.80 m past r01 (contact 0.88 m):
0.871 m apart at 43.5 s, while braking would have stopped it 1.0 m off. Now a softened plan
that comes into contact with a robot it had a side across, where braking straight on would
not, is not used: the fallback brakes or follows the last plan, each checked on its own. (Where
braking touches too, the softened plan may be the lesser contact: `test_mpc_fleet.py`'s robot
passing one at rest at 1 m/s brakes to 0.70 m of it, and steers round it at 0.806 m.) The
case folder is tests/contact_cases/past_a_robot_at_rest (the fuzz case as found, cut from 180 s
to 45 s).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fleet.engine import World
from fleet.scenario import load_scenario
from fleet_plugins.mpc.crowd import touches
from fleet_plugins.mpc.separation import Obstacle

CASE = Path(__file__).resolve().parent / "contact_cases" / "past_a_robot_at_rest"
RADII, MARGIN = 0.88, 0.1


def at_origin(steps: int) -> Obstacle:
    """A robot at rest at the origin, kept clear of by ``RADII + MARGIN``."""
    return Obstacle.square("r01", np.zeros((steps + 1, 2)), RADII + MARGIN, MARGIN)


def test_a_plan_touches_a_robot_only_within_the_sum_of_the_radii() -> None:
    past = np.array([[-3.0, 0.0], [-2.0, 0.0], [-1.0, 0.0], [0.0, 0.0], [1.0, 0.0]])
    for y, touching in ((0.85, True), (0.95, False), (0.90, False)):
        p = past + [0.0, y]
        assert touches(at_origin(4), p) is touching, y
    # Off on a diagonal: inside the square (0.7 < 0.98 on both axes), out of contact (0.99 m).
    diagonal = np.array([[-2.0, 0.7], [-1.4, 0.7], [-0.7, 0.7], [-0.7, 1.4]])
    assert not touches(at_origin(3), diagonal)


def test_contact_between_two_samples_counts() -> None:
    # One step from x = -2 to x = 2 at y = 0.8: the samples are 2.15 m off, the middle 0.8 m.
    p = np.array([[-4.0, 0.8], [-2.0, 0.8], [2.0, 0.8]])
    assert touches(at_origin(2), p)
    # Point 0 is where the robot is now and point 1 fixed by it: only the plan after counts.
    assert not touches(at_origin(2), np.array([[0.0, 0.5], [0.0, 1.5], [0.0, 2.5]]))


def test_the_robot_sliding_past_one_at_rest_keeps_out_of_contact() -> None:
    world = World(load_scenario(CASE / "scen.toml"))
    summary = world.run().summary
    assert summary["violations"]["collision"] == 0
    t, a, _ = world.recorder.trajectories["r01"].arrays()
    t3, b, _ = world.recorder.trajectories["r03"].arrays()
    assert np.array_equal(t, t3) and t[-1] >= 44.0
    least = float(np.min(np.hypot(*(a - b).T)))
    radii = world.robots["r01"].spec.radius + world.robots["r03"].spec.radius
    assert least >= radii - 1e-9, (least, radii)
    assert math.isclose(radii, RADII)

"""An MPC robot a hair outside its regions still solves (issue 16, MPC fuzz case s42-0010).

r02 waited next to r03, which stood on r02's goal, pressed by its plans against an edge of
the free space (a region's face at x = 28.8184). Its speed there, -8.4e-10 m/s, lay below
`fallback.REST_SPEED`, so nothing cancelled it: it drifted across the face, and once its
fixed first plan point was outside every region by more than HiGHS's feasibility tolerance
(1e-9), every solve was infeasible, and so was every new trip from there: 438 infeasible
solves, standing still for the last 150 s of 180. Now a measured position outside the trip's
regions by at most `BOUNDARY_BAND` is taken at the nearest point of the nearest region
(`horizon.into_regions`). The case folder is tests/liveness_cases/mpc_edge_drift (as found).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fleet.floor import BOUNDARY_BAND, load_floor
from fleet.paths import PathPlanner
from fleet.plugins import ControllerContext, ControlStatus, Observation, RobotSpec
from fleet_plugins.mpc.controller import MPCController
from fleet_plugins.mpc.horizon import into_regions

CASE = Path(__file__).resolve().parent / "liveness_cases" / "mpc_edge_drift"
SPEC = RobotSpec(v_max=1.27, a_max=1.88, radius=0.389, period=0.25)
# r02 at t = 61.5 s as the engine observed it (the first infeasible solve), and its goal.
STATE = (28.81839999915861, 39.50338594794136, -8.41382075122965e-10, 1.7053025658242404e-13)
GOAL = (28.4608, 40.2836)


def test_a_robot_a_hair_outside_its_regions_solves_and_moves_back_in() -> None:
    floor = load_floor(CASE / "floor.toml")
    c = MPCController()
    c.reset(ControllerContext("r02", SPEC, floor, PathPlanner(floor, SPEC.v_max, SPEC.a_max)))
    obs = Observation("r02", 246, 61.5, *STATE, goal=GOAL, job="j00004")
    p = np.array(STATE[:2])
    outside = min(float(np.max(r.A @ p - r.b)) for r in floor.regions)
    assert 0.0 < outside <= BOUNDARY_BAND  # outside every region, by a hair
    cmd = c.compute(obs)
    assert cmd.status is ControlStatus.OK and cmd.solve is not None
    assert cmd.solve.outcome.usable
    # The position the solve started from is on a region's edge, within the band of the real one.
    assert c._trip is not None
    moved = into_regions(obs, floor, c._trip)
    q = np.array([moved.x, moved.y])
    assert np.hypot(*(q - p)) <= BOUNDARY_BAND
    assert min(float(np.max(r.A @ q - r.b)) for r in floor.regions) <= 1e-12
    # A robot inside its regions, or farther out than the band, is left as it is.
    inside = Observation("r02", 246, 61.5, p[0] + 1e-3, p[1], 0.0, 0.0, goal=GOAL)
    assert into_regions(inside, floor, c._trip) is inside
    far = Observation("r02", 246, 61.5, p[0] - 1e-3, p[1], 0.0, 0.0, goal=GOAL)
    assert into_regions(far, floor, c._trip) is far

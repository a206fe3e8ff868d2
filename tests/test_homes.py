"""Idle robots of one group trade home spots when that gets a held-up one home sooner
(`fleet.engine.homes`): robots packed round a depot no longer wait for the ones parked between
them and home to make way one after the other."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np

from fleet.engine import World
from fleet.engine.homes import trade_home
from fleet.engine.motion import RobotState
from fleet.plugins import RobotSpec
from fleet.plugins.robot import DoubleIntegrator
from fleet.scenario import load_scenario

CASE = Path(__file__).resolve().parent / "liveness_cases" / "packed_depot"
SPEC = RobotSpec(v_max=1.0, a_max=0.5, radius=0.4, period=0.25)


def robot(rid: str, home: tuple[float, float], at: tuple[float, float], **kw) -> RobotState:
    return RobotState(rid, SPEC, DoubleIntegrator(0.25, 0.5), home, *at, **kw)


def test_a_robot_parked_beside_the_empty_inner_spot_slides_in_for_the_one_held_up() -> None:
    # A row of spots 1 m apart: r1's home (0, 0) is the inner one, r2 parked on (1, 0), r1
    # held up 4 m out. r2 takes (0, 0), r1 gets r2's spot: 16 + 0 -> 9 + 1 (m^2).
    r1, r2 = robot("r1", (0.0, 0.0), (4.0, 0.0)), robot("r2", (1.0, 0.0), (1.0, 0.0))
    assert trade_home(r1, [r1, r2], 0.05) is r2
    assert (r1.home, r2.home) == ((1.0, 0.0), (0.0, 0.0))


def test_no_trade_that_only_moves_a_parked_robot_further() -> None:
    # r1 2 m out in the open, r2 parked 1 m from it: 4 + 0 against 1 + 5.
    r1, r2 = robot("r1", (0.0, 0.0), (2.0, 0.0)), robot("r2", (2.0, 1.0), (2.0, 1.0))
    assert trade_home(r1, [r1, r2], 0.05) is None
    assert (r1.home, r2.home) == ((0.0, 0.0), (2.0, 1.0))


def test_only_idle_robots_of_the_same_group_going_home_trade() -> None:
    def pair(**kw):
        return robot("r1", (0.0, 0.0), (4.0, 0.0)), robot("r2", (1.0, 0.0), (1.0, 0.0), **kw)

    for kw in ({"group": 1}, {"return_home": False}, {"charger_at": (9.0, 9.0)}):
        r1, r2 = pair(**kw)
        assert trade_home(r1, [r1, r2], 0.05) is None, kw
    r1, r2 = pair()
    r2.queue.append(object())  # a job waiting for it
    assert trade_home(r1, [r1, r2], 0.05) is None


def test_twenty_robots_packed_round_a_depot_are_all_home_soon_after_their_jobs(tmp_path) -> None:
    # 20 followers round a depot in a corner, 20 jobs released 1 s apart to three stations.
    # Without trades the last of them was home at 574.5 s (3 still out at 300 s); with them
    # at 204.5 s.
    shutil.copytree(CASE, tmp_path / "case")
    world = World(load_scenario(tmp_path / "case" / "scen.toml"))
    summary = world.run().summary
    assert summary["jobs"]["completed"] == 20
    assert summary["violations"]["collision"] == 0
    starts, ends = [], []
    for rid in world.robots:
        _, xy, _ = world.recorder.trajectories[rid].arrays()
        starts.append(xy[0])
        ends.append(xy[-1])
    starts_a = np.array(starts)
    for rid, end in zip(world.robots, ends, strict=True):
        gaps = np.hypot(*(starts_a - end).T)
        assert gaps.min() <= 0.1, (rid, end, float(gaps.min()))  # on a home spot
        assert math.dist(end, world.robots[rid].home) <= 0.1  # its own, after the trades

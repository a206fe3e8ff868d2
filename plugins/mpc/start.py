"""Setting off from rest next to a higher robot: show the start a tick before moving.

Others see a robot's plan one tick late. A higher robot is held (`neighbours.must_hold`) only
for a close lower robot that moves; against a lower robot at rest it re-plans, keeping clear of
where that one stands, while the lower one keeps clear of the higher one's last plan. Should
both set off at the same tick, each plan keeps clear of the other's old one and the two can
meet (MPC fuzz case s41-0057: both at rest 1.77 m apart, both set off, 0.578 m apart with radii
0.378; tests/test_mpc_start.py). So a lower robot at rest whose plan would set it off while a
higher robot is close (`neighbours.must_announce`) stays at rest for a tick and publishes that
plan one tick late: at the next tick the higher robot sees it moving and holds (it follows its
plan or brakes), and the lower one, solving again, keeps clear of that.
"""

from __future__ import annotations

import math

import numpy as np

from fleet.plugins import Command, ControlStatus, Observation, RobotSpec, SolveReport
from fleet_plugins.mpc.fallback import plan_points
from fleet_plugins.mpc.neighbours import must_announce
from fleet_plugins.mpc.separation import at_rest

__all__ = ["StartGate"]


class StartGate:
    """Decides, for one robot, whether a plan that sets it off is applied or shown first.

    `enabled`: the controller respects priorities and avoids robots; `margin`: its separation
    margin (m), as `neighbours.close` takes it."""

    def __init__(self, enabled: bool, margin: float) -> None:
        self.enabled = enabled
        self.margin = margin
        #: The latest tick time whose published plan showed the robot moving after it.
        self.shown_t = math.nan

    def shown(self, t: float, p: np.ndarray) -> None:
        """Note the plan `p` (steps 0..N from `t`) published at `t`."""
        if not at_rest(p[1:]):
            self.shown_t = t

    def command(
        self, obs: Observation, spec: RobotSpec, p: np.ndarray, u: np.ndarray, report: SolveReport
    ) -> Command:
        """The command for plan `p` (steps 0..N from now) solved at this tick, `u` its first
        input: `u` and `p` as usual; or, the robot being at rest and seen at rest by the others
        (its last plan showed no move) and `p` setting it off while a higher robot is close,
        one that stays at rest this tick and publishes `p` one tick late.

        A plan that stays at rest one more tick before it moves shows its start itself.
        (The controller keeps `p` as its last plan either way: when it was shown late, the
        robot is at rest next tick while `p` has it moving by then, so it is not on `p` and no
        reuse, warm start or fallback follows it.)"""
        late = self.enabled and bool(obs.neighbours) and not at_rest(p[1:3])  # sets off now
        late = late and not abs(obs.t - self.shown_t - spec.period) <= 1e-9  # (nan: never)
        late = late and must_announce(obs, spec, self.margin)
        self.shown(obs.t, p)
        dt = spec.period
        if not late:
            return Command(
                float(u[0]), float(u[1]), ControlStatus.OK, plan_points(obs.t, p, dt), report
            )
        plan = ((obs.t, obs.x, obs.y),) + plan_points(obs.t + dt, p, dt)
        return Command(-obs.vx / dt + 0.0, -obs.vy / dt + 0.0, ControlStatus.OK, plan, report)
